//! The levels of a camera frame as a person aiming the bench needs them: a
//! histogram over full scale, the peak and the saturated share, and the
//! stretch (low and high percentiles) that makes a dim frame visible.
//!
//! Why: a crossed-polarizer frame peaks at a few percent of full scale and
//! shows black without a stretch; the page's live view and histogram read
//! these numbers.

use serde::Serialize;

/// Histogram bins over full scale.
pub const BINS: usize = 64;

/// The levels of one frame.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct Levels {
    /// Full scale of the frame's bit depth, DN.
    pub full_scale: u32,
    /// Pixels per bin, `BINS` equal bins from 0 to full scale.
    pub histogram: Vec<u32>,
    /// The brightest pixel, as a fraction of full scale.
    pub peak: f64,
    /// The share of pixels at full scale (saturated).
    pub saturated: f64,
    /// The 0.5th percentile, DN: the black of the auto-contrast stretch.
    pub low: u32,
    /// The 99.5th percentile, DN: the white of the auto-contrast stretch.
    pub high: u32,
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
    let mut histogram = vec![0u32; BINS];
    for (dn, &c) in counts.iter().enumerate() {
        histogram[(dn * BINS / (full as usize + 1)).min(BINS - 1)] += c;
    }
    let peak = counts.iter().rposition(|&c| c > 0).unwrap_or(0) as f64 / f64::from(full);
    let (low, high) = (percentile(0.005), percentile(0.995));
    Some(Levels {
        full_scale: full,
        histogram,
        peak,
        saturated: f64::from(counts[full as usize]) / n,
        low,
        high: high.max(low + 1),
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
        assert_eq!(l.histogram[1], 1000, "100..115 DN is bin 1 of 64 over 4096");
        let shown = display_u16(&px, &l, true);
        assert_eq!(
            (shown.iter().min(), shown.iter().max()),
            (Some(&0), Some(&65535))
        );
        let plain = display_u16(&px, &l, false);
        assert!(*plain.iter().max().unwrap() < 2000);
    }

    #[test]
    fn saturated_pixels_are_counted_and_nothing_is_none() {
        let l = levels(&[255, 255, 0, 10], 8).unwrap();
        assert_eq!((l.saturated, l.peak), (0.5, 1.0));
        assert_eq!(l.histogram[BINS - 1], 2);
        assert_eq!(levels(&[], 8), None);
    }
}
