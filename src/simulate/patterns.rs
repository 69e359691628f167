//! Test patterns for the hidden scene on any grid: a disk, vertical bars and
//! the letter F (asymmetric, so a flipped or transposed recovery shows), and
//! a flat white field (what a colour calibration is measured from).
//!
//! Each is drawn on a 0..1 square and averaged over 4x4 sub-samples per
//! element, so coarse grids get grey edges instead of aliasing.

use crate::scene::Grid;

/// A named test pattern.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Pattern {
    /// Bright disk of radius 0.3 in the middle.
    Disk,
    /// Three vertical bars.
    Bars,
    /// The letter F, upside down on the plane (see [`Pattern::render`]).
    Letter,
    /// The whole plane white: the field a colour calibration measures.
    Flat,
}

impl Pattern {
    /// Every pattern with a shape to recover, in a fixed order (not `Flat`).
    pub const ALL: [Pattern; 3] = [Pattern::Disk, Pattern::Bars, Pattern::Letter];

    /// Parses `disk`, `bars`, `letter` or `flat`.
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "disk" => Some(Pattern::Disk),
            "bars" => Some(Pattern::Bars),
            "letter" => Some(Pattern::Letter),
            "flat" => Some(Pattern::Flat),
            _ => None,
        }
    }

    /// The pattern's name.
    pub fn name(self) -> &'static str {
        match self {
            Pattern::Disk => "disk",
            Pattern::Bars => "bars",
            Pattern::Letter => "letter",
            Pattern::Flat => "flat",
        }
    }

    fn at(self, x: f64, y: f64) -> bool {
        match self {
            Pattern::Disk => (x - 0.5).hypot(y - 0.5) <= 0.3,
            Pattern::Bars => {
                (0.15..0.85).contains(&y)
                    && [0.15, 0.42, 0.69]
                        .iter()
                        .any(|a| (*a..a + 0.16).contains(&x))
            }
            Pattern::Letter => {
                let stem = (0.25..0.42).contains(&x) && (0.12..0.88).contains(&y);
                let top = (0.25..0.78).contains(&x) && (0.12..0.28).contains(&y);
                let mid = (0.25..0.66).contains(&x) && (0.44..0.58).contains(&y);
                stem || top || mid
            }
            Pattern::Flat => true,
        }
    }

    /// Values in [0, 1] on `grid`, in its element order (row `iv` = 0 at
    /// the plane's -v edge): the shape's `y` runs from row 0, so on the
    /// plane the letter's top bar lies at the -v edge (its bottom) and the F
    /// stands upside down seen from in front. Every bench, test and figure
    /// was measured on this layout. Written top row first (`pattern`'s PNG,
    /// the daemon's `truth.png`, Python's `pattern`; docs/formats.md "Which
    /// way is up") it therefore shows the F mirrored top to bottom: its bar
    /// at the bottom, its open end at the top. Disk, bars and flat are
    /// symmetric along v and look the same either way.
    pub fn render(self, grid: Grid) -> Vec<f64> {
        coverage(grid, 4, |x, y| self.at(x, y))
    }
}

/// Each element's covered fraction of a shape on `grid`: `inside(x, y)`
/// at `samples` x `samples` points an element, `x` and `y` in [0, 1]
/// across the grid in its element order (`x` along the columns, `y` along
/// the rows from row 0).
/// Why: one sampling for the test patterns and the demo's moving disk.
pub(crate) fn coverage(grid: Grid, samples: usize, inside: impl Fn(f64, f64) -> bool) -> Vec<f64> {
    let s = samples.max(1);
    let mut out = Vec::with_capacity(grid.count());
    for iv in 0..grid.nv {
        for iu in 0..grid.nu {
            let mut hits = 0;
            for b in 0..s {
                for a in 0..s {
                    let x = (iu as f64 + (a as f64 + 0.5) / s as f64) / grid.nu as f64;
                    let y = (iv as f64 + (b as f64 + 0.5) / s as f64) / grid.nv as f64;
                    hits += usize::from(inside(x, y));
                }
            }
            out.push(hits as f64 / (s * s) as f64);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patterns_are_distinct_and_in_range() {
        let g = Grid { nu: 16, nv: 16 };
        let imgs: Vec<Vec<f64>> = Pattern::ALL.iter().map(|p| p.render(g)).collect();
        for img in &imgs {
            assert!(img.iter().all(|v| (0.0..=1.0).contains(v)));
            let lit = img.iter().sum::<f64>() / 256.0;
            assert!(lit > 0.15 && lit < 0.5, "{lit}");
        }
        assert_ne!(imgs[0], imgs[1]);
        // The letter is not mirror-symmetric left to right.
        let l = &imgs[2];
        let mirrored: Vec<f64> = (0..256).map(|j| l[(j / 16) * 16 + 15 - j % 16]).collect();
        assert_ne!(*l, mirrored);
    }

    #[test]
    fn the_letter_lies_with_its_bar_at_the_plane_s_minus_v_edge() {
        // The layout every measured figure used: the F's top bar in the
        // grid's first rows (the plane's -v edge), its open foot in the
        // last; written top row first, the bar is in the image's last rows.
        let g = Grid { nu: 16, nv: 16 };
        let f = Pattern::Letter.render(g);
        let lit = |img: &[f64], r: usize| img[r * 16..(r + 1) * 16].iter().sum::<f64>();
        assert!(
            lit(&f, 3) > 2.0 * lit(&f, 13),
            "{} {}",
            lit(&f, 3),
            lit(&f, 13)
        );
        let top = g.to_top_first(&f, 1);
        assert!(
            lit(&top, 12) > 2.0 * lit(&top, 2),
            "{} {}",
            lit(&top, 12),
            lit(&top, 2)
        );
    }
}
