//! The levels of a camera frame as a person aiming the bench needs them: a
//! histogram over full scale, the peak and the saturated share, and the
//! stretch (low and high percentiles) that makes a dim frame visible.
//!
//! Why: a crossed-polarizer frame peaks at a few percent of full scale and
//! shows black without a stretch; the page's live view and histogram read
//! these numbers.

use serde::Serialize;

/// Histogram bins over the range the frame uses.
pub(crate) const BINS: usize = 64;

/// The narrowest stretch and histogram range, DN, at `full` scale: 1/512 of
/// full scale and at least 8 DN. Why: a frame of read noise alone spans a
/// DN or two, and stretching that to black..white shows noise as an image.
pub(crate) fn min_span(full: u32) -> u32 {
    (full / 512).max(8).min(full)
}

/// The levels of one frame.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct Levels {
    /// Full scale of the frame's bit depth, DN.
    pub full_scale: u32,
    /// Pixels per bin, `BINS` equal bins from `histogram_low` to
    /// `histogram_high` DN: the range the frame uses, at least
    /// [`min_span`] wide, so that a dim frame's pixels spread over the bins.
    pub histogram: Vec<u32>,
    /// The darkest DN the histogram covers.
    pub histogram_low: u32,
    /// The brightest DN the histogram covers.
    pub histogram_high: u32,
    /// The brightest pixel, as a fraction of full scale.
    pub peak: f64,
    /// The share of pixels at full scale (saturated).
    pub saturated: f64,
    /// The black of the auto-contrast stretch, DN: the 0.5th percentile,
    /// lowered when the span would be narrower than [`min_span`].
    pub low: u32,
    /// The white of the auto-contrast stretch, DN: the 99.5th percentile,
    /// raised when the span would be narrower than [`min_span`].
    pub high: u32,
}

/// `lo..hi` widened about its middle to at least `span`, within `0..=full`.
fn widen(lo: u32, hi: u32, span: u32, full: u32) -> (u32, u32) {
    if hi - lo >= span {
        return (lo, hi);
    }
    let mid = (lo + hi) / 2;
    let lo = mid.saturating_sub(span / 2).min(full - span);
    (lo, lo + span)
}

/// The levels of `pixels` at `bits` per pixel (1 to 16); `None` for no pixels.
pub fn levels(pixels: &[u16], bits: u32) -> Option<Levels> {
    if pixels.is_empty() {
        return None;
    }
    let full = (1u32 << bits.clamp(1, 16)) - 1;
    // Counting sort over the DN range: exact percentiles in one pass.
    let mut counts = vec![0u32; full as usize + 1];
    for &p in pixels {
        counts[u32::from(p).min(full) as usize] += 1;
    }
    let n = pixels.len() as f64;
    let percentile = |q: f64| {
        let want = (q * n).ceil().max(1.0) as u64;
        let mut seen = 0u64;
        counts
            .iter()
            .position(|&c| {
                seen += u64::from(c);
                seen >= want
            })
            .unwrap_or(full as usize) as u32
    };
    let span = min_span(full);
    let darkest = counts.iter().position(|&c| c > 0).unwrap_or(0) as u32;
    let brightest = counts.iter().rposition(|&c| c > 0).unwrap_or(0) as u32;
    let (h_lo, h_hi) = widen(darkest, brightest, span, full);
    let width = (h_hi - h_lo + 1) as usize;
    let mut histogram = vec![0u32; BINS];
    for (dn, &c) in counts.iter().enumerate().skip(h_lo as usize).take(width) {
        histogram[((dn - h_lo as usize) * BINS / width).min(BINS - 1)] += c;
    }
    let (low, high) = widen(percentile(0.005), percentile(0.995), span, full);
    Some(Levels {
        full_scale: full,
        histogram,
        histogram_low: h_lo,
        histogram_high: h_hi,
        peak: f64::from(brightest) / f64::from(full),
        saturated: f64::from(counts[full as usize]) / n,
        low,
        high,
    })
}

/// `pixels` mapped onto 16 bits: `low..high` DN to black..white when
/// `stretch` (auto-contrast), else full scale to white.
pub fn display_u16(pixels: &[u16], levels: &Levels, stretch: bool) -> Vec<u16> {
    let (lo, hi) = if stretch {
        (f64::from(levels.low), f64::from(levels.high))
    } else {
        (0.0, f64::from(levels.full_scale))
    };
    let span = (hi - lo).max(1.0);
    pixels
        .iter()
        .map(|&p| {
            ((f64::from(p) - lo) / span * 65535.0)
                .round()
                .clamp(0.0, 65535.0) as u16
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_dim_frame_peaks_low_and_stretches_to_full_range() {
        // A 12-bit frame between 100 and 115 DN (2.8 % of full scale).
        let px: Vec<u16> = (0..1000).map(|k| 100 + (k % 16) as u16).collect();
        let l = levels(&px, 12).unwrap();
        assert_eq!(l.full_scale, 4095);
        assert!((l.peak - 115.0 / 4095.0).abs() < 1e-12);
        assert_eq!((l.low, l.high, l.saturated), (100, 115, 0.0));
        assert_eq!(l.histogram.iter().sum::<u32>(), 1000);
        // The histogram covers the range used: its 16 levels over 64 bins.
        assert_eq!((l.histogram_low, l.histogram_high), (100, 115));
        assert_eq!(l.histogram.iter().filter(|&&c| c > 0).count(), 16);
        let shown = display_u16(&px, &l, true);
        assert_eq!(
            (shown.iter().min(), shown.iter().max()),
            (Some(&0), Some(&65535))
        );
        let plain = display_u16(&px, &l, false);
        assert!(*plain.iter().max().unwrap() < 2000);
    }

    #[test]
    fn a_frame_of_one_dn_of_noise_is_not_stretched_to_black_and_white() {
        // The fake camera before its first capture: 655 and 656 DN (16 bits).
        let px: Vec<u16> = (0..4096).map(|k| 655 + (k % 2) as u16).collect();
        let l = levels(&px, 16).unwrap();
        let span = min_span(65535);
        assert_eq!(span, 127);
        assert_eq!(l.high - l.low, span);
        assert!(l.low <= 655 && l.high >= 656, "{l:?}");
        let shown = display_u16(&px, &l, true);
        let (lo, hi) = (shown.iter().min().unwrap(), shown.iter().max().unwrap());
        // One DN in 127: a grey with a 1 % ripple, not black and white.
        assert!(hi - lo < 1000 && *lo > 20_000 && *hi < 45_000, "{lo}..{hi}");
        // Its histogram spans the same narrow range, the two levels apart.
        assert_eq!(l.histogram_high - l.histogram_low, span);
        assert_eq!(l.histogram.iter().filter(|&&c| c > 0).count(), 2);
        // At the top of the range the span stays within full scale.
        let l = levels(&[65535, 65534], 16).unwrap();
        assert_eq!((l.high, l.histogram_high), (65535, 65535));
        assert_eq!(l.high - l.low, span);
    }

    #[test]
    fn saturated_pixels_are_counted_and_nothing_is_none() {
        let l = levels(&[255, 255, 0, 10], 8).unwrap();
        assert_eq!((l.saturated, l.peak), (0.5, 1.0));
        assert_eq!((l.histogram_low, l.histogram_high), (0, 255));
        assert_eq!(l.histogram[BINS - 1], 2);
        assert_eq!(levels(&[], 8), None);
    }
}
