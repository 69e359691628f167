//! A colour sensor's Bayer filter: which of a 2x2 cell's pixels see red,
//! green and blue, so each colour's measurement is made from its own pixels.
//!
//! Each element's value for a colour is the mean over all its pixels of
//! that colour bilinearly interpolated from its own pixels
//! ([`crate::scene::PixelMap::interpolated`]): a weighted sum of the
//! colour's pixels, centred on the element as `T`'s row is (their plain
//! mean sits half a pixel off).

use crate::scene::Cells;
pub use crate::scene::Colour;

/// The 2x2 pattern of a Bayer filter, named as GenICam's pixel formats name
/// it (PFNC `BayerRG8` ...): the colours of the cell's first row, left to
/// right, then the second row follows with green and the remaining colour.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize, utoipa::ToSchema,
)]
pub enum BayerPattern {
    /// R G / G B.
    RG,
    /// G R / B G.
    GR,
    /// G B / R G.
    GB,
    /// B G / G R.
    BG,
}

/// A Bayer pattern name that is none of the four (the name as given).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0:?} is not a Bayer pattern; give RG, GR, GB or BG (the colours of the sensor's first row, as BayerRG16 names RG)")]
pub struct UnknownBayerPattern(pub String);

impl std::str::FromStr for BayerPattern {
    type Err = UnknownBayerPattern;

    /// A pattern by its first row's colours (`RG` or `RGGB`, ...), as a
    /// camera's pixel format names it; the CLI's `--bayer` and the daemon's
    /// `?bayer=` read it alike.
    fn from_str(s: &str) -> Result<Self, UnknownBayerPattern> {
        match s.to_ascii_uppercase().as_str() {
            "RG" | "RGGB" => Ok(BayerPattern::RG),
            "GR" | "GRBG" => Ok(BayerPattern::GR),
            "GB" | "GBRG" => Ok(BayerPattern::GB),
            "BG" | "BGGR" => Ok(BayerPattern::BG),
            _ => Err(UnknownBayerPattern(s.to_string())),
        }
    }
}

impl BayerPattern {
    /// The colour of sensor pixel `(x, y)` (column, row from the sensor's first pixel).
    pub fn colour_at(self, x: i64, y: i64) -> Colour {
        let (cx, cy) = (x.rem_euclid(2), y.rem_euclid(2));
        let red = self.red();
        let red = (i64::from(red[0]), i64::from(red[1]));
        if (cx, cy) == red {
            Colour::Red
        } else if (cx, cy) == (1 - red.0, 1 - red.1) {
            Colour::Blue
        } else {
            Colour::Green
        }
    }

    /// The column and row mod 2 of the red pixel (blue is the opposite corner).
    fn red(self) -> [u32; 2] {
        match self {
            BayerPattern::RG => [0, 0],
            BayerPattern::GR => [1, 0],
            BayerPattern::GB => [0, 1],
            BayerPattern::BG => [1, 1],
        }
    }

    /// The pixels that see `colour`: one position of the 2x2 cell for red
    /// and blue, the other two for green.
    pub fn cells(self, colour: Colour) -> Cells {
        let [x, y] = self.red();
        match colour {
            Colour::Red => Cells::one([x, y]),
            Colour::Blue => Cells::one([1 - x, 1 - y]),
            Colour::Green => Cells::any(&[[1 - x, y], [x, 1 - y]]),
        }
    }
}

/// A raw Bayer frame (`pixels`, `width` x `height`, its first pixel at
/// sensor column and row `offset`) in colour at half resolution: each whole
/// 2x2 cell one RGB pixel, red, the mean of its two greens and blue,
/// interleaved. Cells start at the first pixel with even sensor coordinates.
///
/// Why cells: the live view shows what the camera measured, not a
/// demosaicing guess, as the polarizer mosaic's Stokes views do.
pub(crate) fn cells_rgb(
    pixels: &[u16],
    (width, height): (usize, usize),
    pattern: BayerPattern,
    offset: [u32; 2],
) -> (usize, usize, Vec<u16>) {
    let (x0, y0) = ((offset[0] % 2) as usize, (offset[1] % 2) as usize);
    let w = width.saturating_sub(x0) / 2;
    let h = height.saturating_sub(y0) / 2;
    let mut out = Vec::with_capacity(3 * w * h);
    for cy in 0..h {
        for cx in 0..w {
            let mut sum = [0u32; 3];
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let (x, y) = (x0 + 2 * cx + dx, y0 + 2 * cy + dy);
                let c = pattern.colour_at(
                    i64::from(offset[0]) + x as i64,
                    i64::from(offset[1]) + y as i64,
                );
                sum[c as usize] += u32::from(pixels.get(y * width + x).copied().unwrap_or(0));
            }
            out.extend([sum[0] as u16, (sum[1] / 2) as u16, sum[2] as u16]);
        }
    }
    (w, h, out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_pattern_puts_its_colours_where_its_name_says() {
        // First row left to right, second row left to right.
        let cases = [
            (BayerPattern::RG, "RGGB"),
            (BayerPattern::GR, "GRBG"),
            (BayerPattern::GB, "GBRG"),
            (BayerPattern::BG, "BGGR"),
        ];
        for (p, name) in cases {
            let got: String = [(0, 0), (1, 0), (0, 1), (1, 1)]
                .iter()
                .map(|&(x, y)| match p.colour_at(x, y) {
                    Colour::Red => 'R',
                    Colour::Green => 'G',
                    Colour::Blue => 'B',
                })
                .collect();
            assert_eq!(got, name, "{p:?}");
            // The pattern repeats every two pixels, negative coordinates too.
            assert_eq!(p.colour_at(-2, 4), p.colour_at(0, 0));
            assert_eq!(p.colour_at(3, -1), p.colour_at(1, 1));
        }
    }

    #[test]
    fn a_raw_frame_shows_in_colour_one_pixel_per_cell() {
        // GB: G B / R G; red 100, greens 200 and 220, blue 300; a 5x3 frame
        // at an odd offset (1, 0): cells start at its second column.
        let pattern = BayerPattern::GB;
        let level = |x: i64, y: i64| match pattern.colour_at(x, y) {
            Colour::Red => 100,
            Colour::Blue => 300,
            Colour::Green if y % 2 == 0 => 200,
            Colour::Green => 220,
        };
        let pixels: Vec<u16> = (0..15).map(|k| level(1 + k % 5, k / 5)).collect();
        let (w, h, rgb) = cells_rgb(&pixels, (5, 3), pattern, [1, 0]);
        assert_eq!((w, h), (2, 1));
        assert_eq!(rgb, vec![100, 210, 300, 100, 210, 300]);
    }

    #[test]
    fn the_colours_cells_split_the_sensor_one_two_one() {
        for p in [
            BayerPattern::RG,
            BayerPattern::GR,
            BayerPattern::GB,
            BayerPattern::BG,
        ] {
            for y in 0..4 {
                for x in 0..4 {
                    let inside: Vec<Colour> = Colour::ALL
                        .into_iter()
                        .filter(|&c| p.cells(c).contains(x, y))
                        .collect();
                    assert_eq!(inside, vec![p.colour_at(x, y)], "{p:?} at {x},{y}");
                }
            }
        }
        let g = BayerPattern::RG.cells(Colour::Green);
        assert!(g.in_row(0) && g.in_row(1));
        let r = BayerPattern::RG.cells(Colour::Red);
        assert!(r.in_row(0) && !r.in_row(1));
    }
}
