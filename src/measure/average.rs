//! Averaging a stack of frames: the running mean and variance of the mean
//! per pixel (Welford), and the dark frame taken off the mean.
//!
//! Why here: the daemon (while frames arrive) and `polnlos measure` (from a
//! user's TIFF) must turn frames into the same mean and the same variance.

use super::MeasureError;
use crate::scene::Frame;

/// Pixels at the ends of the camera's range in a stack of raw frames.
///
/// Why: a pixel at full scale says only "at least this much"; a mean over it
/// is biased low and nothing downstream can tell, so a capture says how many
/// it had (issue 38: 28,600 saturated pixels in one frame went unreported).
#[derive(
    Debug,
    Clone,
    Copy,
    Default,
    PartialEq,
    Eq,
    serde::Serialize,
    serde::Deserialize,
    utoipa::ToSchema,
)]
pub struct Clipping {
    /// The most pixels at full scale (`2^bits - 1`) in any one frame.
    pub saturated: u64,
    /// The most pixels at zero in any one frame.
    pub zero: u64,
    /// Frames with at least one pixel at full scale.
    pub frames_saturated: u64,
    /// Pixels per frame (the share's denominator).
    pub pixels: u64,
}

impl Clipping {
    /// The largest share of one frame's pixels at full scale, 0..1.
    pub fn saturated_share(&self) -> f64 {
        if self.pixels == 0 {
            0.0
        } else {
            self.saturated as f64 / self.pixels as f64
        }
    }

    /// The saturation in words, with what to do about it: one text for the
    /// capture's log or failure and for the reconstructions that use it.
    pub fn saturation(&self, scene: &str) -> String {
        format!(
            "{} of {} pixels at full scale in one frame ({:.2} %), in {} frames; lower exposure_us (GET /scenes/{scene}/exposure gives one per block)",
            self.saturated,
            self.pixels,
            100.0 * self.saturated_share(),
            self.frames_saturated,
        )
    }

    /// Counts one frame of raw values whose full scale is `2^bits - 1`
    /// (bits outside 1..=16, which no camera reports, count against 65535).
    fn count(&mut self, pixels: &[u16], bits: u32) {
        let full = full_scale(bits);
        let (mut at_full, mut at_zero) = (0u64, 0u64);
        for &p in pixels {
            at_full += u64::from(p >= full);
            at_zero += u64::from(p == 0);
        }
        self.saturated = self.saturated.max(at_full);
        self.zero = self.zero.max(at_zero);
        self.frames_saturated += u64::from(at_full > 0);
        self.pixels = pixels.len() as u64;
    }
}

/// Full scale of raw values `bits` deep (bits outside 1..=16, which no
/// camera reports, count against 65535).
fn full_scale(bits: u32) -> u16 {
    if (1..=16).contains(&bits) {
        ((1u32 << bits) - 1) as u16
    } else {
        u16::MAX
    }
}

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
    /// Pixels at the ends of the range, of the frames added by [`Self::push_raw`].
    pub clipping: Clipping,
    /// Which pixels were at full scale in at least one frame added by
    /// [`Self::push_raw`]; empty until one was.
    saturated: Vec<bool>,
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
            clipping: Clipping::default(),
            saturated: Vec::new(),
        }
    }

    /// Adds one frame of a camera's raw values, `bits` deep, counting its
    /// pixels at full scale and at zero (`Clipping`).
    pub fn push_raw(&mut self, pixels: &[u16], bits: u32) {
        let before = self.clipping.frames_saturated;
        self.clipping.count(pixels, bits);
        if self.clipping.frames_saturated > before {
            let full = full_scale(bits);
            if self.saturated.is_empty() {
                self.saturated = vec![false; self.width * self.height];
            }
            for (s, &p) in self.saturated.iter_mut().zip(pixels) {
                *s |= p >= full;
            }
        }
        self.push(pixels);
    }

    /// Which pixels were at full scale in at least one frame ([`Self::push_raw`]),
    /// `None` when none was.
    ///
    /// Why: such a pixel's mean is only a lower bound; a measurement leaves
    /// it out of its element's mean (issue 38).
    pub fn saturated_pixels(&self) -> Option<&[bool]> {
        (!self.saturated.is_empty()).then_some(self.saturated.as_slice())
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
    fn clipped_pixels_are_counted_against_the_frames_own_bit_depth() {
        let mut st = FrameStack::new(4, 1);
        // 12-bit frames: 4095 is full scale, 4094 is not.
        st.push_raw(&[4095, 4094, 0, 7], 12);
        st.push_raw(&[4095, 4095, 0, 0], 12);
        st.push_raw(&[1, 2, 3, 4], 12);
        assert_eq!(
            st.clipping,
            Clipping {
                saturated: 2,
                zero: 2,
                frames_saturated: 2,
                pixels: 4
            }
        );
        assert_eq!(st.clipping.saturated_share(), 0.5);
        assert!((st.mean[0] - (4095.0 + 4095.0 + 1.0) / 3.0).abs() < 1e-9);
        // 8-bit values are saturated at 255; 16-bit at 65535.
        let mut st = FrameStack::new(2, 1);
        st.push_raw(&[255, 65535], 8);
        assert_eq!(st.clipping.saturated, 2);
        let mut st = FrameStack::new(2, 1);
        st.push_raw(&[255, 65534], 16);
        assert_eq!(st.clipping.saturated, 0);
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

    #[test]
    fn pixels_at_full_scale_in_any_frame_are_marked() {
        let mut st = FrameStack::new(3, 1);
        st.push_raw(&[4095, 10, 20], 12);
        assert_eq!(st.saturated_pixels(), Some(&[true, false, false][..]));
        st.push_raw(&[100, 10, 4095], 12);
        assert_eq!(st.saturated_pixels(), Some(&[true, false, true][..]));
        let mut clean = FrameStack::new(2, 1);
        clean.push_raw(&[4094, 0], 12);
        assert_eq!(clean.saturated_pixels(), None);
    }
}
