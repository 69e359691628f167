//! The mean and variance of the last `n` frames of a stream (a rolling
//! window), updated per frame in one pass over the pixels.
//!
//! Why: live reconstruction solves the newest window after every frame; a
//! [`super::FrameStack`] only grows, and re-averaging the window would cost
//! `n` passes a frame. Sums of whole DN values (and of their squares) are
//! exact in `f64` far beyond any window this allows, so removing the oldest
//! frame leaves no rounding drift, however long the stream runs.

use std::collections::VecDeque;

/// Largest window: 64 frames of 16-bit values keep the sums of squares
/// below 2^38, exact in `f64`, and a window's memory at 64 frames.
pub const MAX_WINDOW: usize = 64;

/// The last `n` frames of `width` x `height` raw values and their sums.
#[derive(Debug, Clone)]
pub struct Window {
    width: usize,
    height: usize,
    n: usize,
    frames: VecDeque<Vec<u16>>,
    sum: Vec<f64>,
    sum_sq: Vec<f64>,
}

/// Why a frame cannot join a window.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum WindowError {
    /// The window size is outside `1..=MAX_WINDOW`.
    #[error("a window of {0} frames: give 1 to {MAX_WINDOW}")]
    Size(usize),
    /// A frame of another size than the window's.
    #[error("a {got_w}x{got_h} frame in a window of {width}x{height} frames")]
    FrameSize {
        /// The frame's columns.
        got_w: usize,
        /// The frame's rows.
        got_h: usize,
        /// The window's columns.
        width: usize,
        /// The window's rows.
        height: usize,
    },
}

impl Window {
    /// An empty window of the last `n` frames of `width` x `height` pixels.
    pub fn new(n: usize, width: usize, height: usize) -> Result<Self, WindowError> {
        if !(1..=MAX_WINDOW).contains(&n) {
            return Err(WindowError::Size(n));
        }
        Ok(Self {
            width,
            height,
            n,
            frames: VecDeque::with_capacity(n),
            sum: vec![0.0; width * height],
            sum_sq: vec![0.0; width * height],
        })
    }

    /// Adds `pixels` (row-major, `width` x `height`), dropping the oldest
    /// frame once the window is full.
    pub fn push(&mut self, width: usize, height: usize, pixels: &[u16]) -> Result<(), WindowError> {
        if (width, height) != (self.width, self.height) || pixels.len() != width * height {
            return Err(WindowError::FrameSize {
                got_w: width,
                got_h: height,
                width: self.width,
                height: self.height,
            });
        }
        let oldest = if self.frames.len() == self.n {
            self.frames.pop_front()
        } else {
            None
        };
        match &oldest {
            Some(old) => {
                for (((s, q), &p), &o) in self
                    .sum
                    .iter_mut()
                    .zip(&mut self.sum_sq)
                    .zip(pixels)
                    .zip(old)
                {
                    let (p, o) = (f64::from(p), f64::from(o));
                    *s += p - o;
                    *q += p * p - o * o;
                }
            }
            None => {
                for ((s, q), &p) in self.sum.iter_mut().zip(&mut self.sum_sq).zip(pixels) {
                    let p = f64::from(p);
                    *s += p;
                    *q += p * p;
                }
            }
        }
        // The oldest frame's buffer holds the newest: no allocation once full.
        let mut slot = oldest.unwrap_or_default();
        slot.clear();
        slot.extend_from_slice(pixels);
        self.frames.push_back(slot);
        Ok(())
    }

    /// Frames in the window now.
    pub fn count(&self) -> usize {
        self.frames.len()
    }

    /// Columns and rows of its frames.
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// Per-pixel mean of the window, DN (zeros while empty).
    pub fn mean(&self) -> Vec<f64> {
        let k = self.count().max(1) as f64;
        self.sum.iter().map(|s| s / k).collect()
    }

    /// Per-pixel variance of the mean (sample variance / count), as
    /// [`super::FrameStack::variance_of_mean`] gives it; None under two frames.
    pub fn variance_of_mean(&self) -> Option<Vec<f64>> {
        let k = self.count();
        (k >= 2).then(|| {
            let kf = k as f64;
            self.sum
                .iter()
                .zip(&self.sum_sq)
                .map(|(s, q)| ((q - s * s / kf) / (kf - 1.0)).max(0.0) / kf)
                .collect()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::measure::FrameStack;
    use proptest::prelude::*;

    #[test]
    fn sizes_outside_the_range_and_frames_of_another_size_are_refused() {
        assert_eq!(Window::new(0, 2, 2).unwrap_err(), WindowError::Size(0));
        assert!(Window::new(MAX_WINDOW + 1, 2, 2).is_err());
        let mut w = Window::new(2, 2, 2).unwrap();
        assert!(w.push(3, 2, &[0; 6]).is_err());
        assert!(w.push(2, 2, &[0; 3]).is_err());
        assert_eq!(w.count(), 0);
    }

    proptest! {
        /// After any stream, the window's mean and variance are those of a
        /// FrameStack of its last `n` frames.
        #[test]
        fn the_window_is_the_stack_of_its_last_frames(
            n in 1usize..6,
            frames in prop::collection::vec(prop::collection::vec(any::<u16>(), 6), 1..20),
        ) {
            let mut w = Window::new(n, 3, 2).unwrap();
            for f in &frames {
                w.push(3, 2, f).unwrap();
            }
            let mut st = FrameStack::new(3, 2);
            for f in &frames[frames.len().saturating_sub(n)..] {
                st.push(f);
            }
            prop_assert_eq!(w.count(), st.count);
            for (a, b) in w.mean().iter().zip(&st.mean) {
                prop_assert!((a - b).abs() <= 1e-9 * b.abs().max(1.0));
            }
            match (w.variance_of_mean(), st.variance_of_mean()) {
                (Some(a), Some(b)) => {
                    for (x, y) in a.iter().zip(&b) {
                        prop_assert!((x - y).abs() <= 1e-6 * y.abs().max(1.0), "{} vs {}", x, y);
                    }
                }
                (None, None) => {}
                (a, b) => prop_assert!(false, "{:?} vs {:?}", a.is_some(), b.is_some()),
            }
        }
    }
}
