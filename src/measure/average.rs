//! Averaging a stack of frames: the running mean and variance of the mean
//! per pixel (Welford), and the dark frame taken off the mean.
//!
//! Why here: the daemon (while frames arrive) and `polnlos measure` (from a
//! user's TIFF) must turn frames into the same mean and the same variance.

use super::MeasureError;
use crate::measure::Frame;

/// The running mean and variance of a stack of equal-size frames (Welford),
/// so that a capture of any length holds two images in memory, not its frames.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameStack {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Frames seen.
    pub count: usize,
    /// Per-pixel mean, DN.
    pub mean: Vec<f64>,
    m2: Vec<f64>,
}

impl FrameStack {
    /// An empty stack of `width` x `height` frames.
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            count: 0,
            mean: vec![0.0; width * height],
            m2: vec![0.0; width * height],
        }
    }

    /// Adds one frame of raw pixel values (its length is the caller's to
    /// check against `width * height`; extra values are ignored).
    pub fn push<T: Copy + Into<f64>>(&mut self, pixels: &[T]) {
        self.count += 1;
        let n = self.count as f64;
        for ((m, m2), &p) in self.mean.iter_mut().zip(self.m2.iter_mut()).zip(pixels) {
            let x: f64 = p.into();
            let d = x - *m;
            *m += d / n;
            *m2 += d * (x - *m);
        }
    }

    /// Per-pixel variance of the mean (sample variance / count); None under two frames.
    pub fn variance_of_mean(&self) -> Option<Vec<f64>> {
        (self.count >= 2).then(|| {
            let n = self.count as f64;
            self.m2
                .iter()
                .map(|m2| (m2 / (n - 1.0)).max(0.0) / n)
                .collect()
        })
    }

    /// The mean as a frame, minus `dark` (the mean dark frame) when given.
    pub fn mean_minus(&self, dark: Option<&Frame>) -> Result<Frame, MeasureError> {
        let mut mean = Frame {
            width: self.width,
            height: self.height,
            pixels: self.mean.iter().map(|&v| v as f32).collect(),
        };
        if let Some(d) = dark {
            if (d.width, d.height) != (self.width, self.height) {
                return Err(MeasureError::DarkSize {
                    dark: [d.width, d.height],
                    frames: [self.width, self.height],
                });
            }
            for (m, (&f, &k)) in mean.pixels.iter_mut().zip(self.mean.iter().zip(&d.pixels)) {
                *m = (f - f64::from(k)) as f32;
            }
        }
        Ok(mean)
    }

    /// The variance of the mean as a frame, None under two frames.
    pub fn variance_frame(&self) -> Option<Frame> {
        self.variance_of_mean().map(|v| Frame {
            width: self.width,
            height: self.height,
            pixels: v.iter().map(|&x| x as f32).collect(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mean_and_variance_of_the_mean_follow_the_frames() {
        let mut st = FrameStack::new(2, 1);
        st.push(&[100u16, 10]);
        assert_eq!(st.variance_of_mean(), None);
        st.push(&[110u16, 10]);
        assert_eq!(st.mean, vec![105.0, 10.0]);
        // Sample variance 50, of the mean 25; a constant pixel has none.
        assert_eq!(st.variance_of_mean(), Some(vec![25.0, 0.0]));
        let dark = Frame {
            width: 2,
            height: 1,
            pixels: vec![5.0, 10.0],
        };
        assert_eq!(st.mean_minus(Some(&dark)).unwrap().pixels, vec![100.0, 0.0]);
    }

    #[test]
    fn a_dark_frame_of_another_size_is_refused_with_both_sizes() {
        let mut st = FrameStack::new(2, 1);
        st.push(&[1u8, 2]);
        let e = st.mean_minus(Some(&Frame::zeros(1, 2))).unwrap_err();
        assert_eq!(
            e.to_string(),
            "the dark frame is 1x2 but the frames are 2x1; take the dark with the same region and binning"
        );
    }
}
