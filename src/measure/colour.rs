//! A colour sensor's Bayer filter: which of a 2x2 cell's pixels see red,
//! green and blue, so each colour's measurement is made from its own pixels.
//!
//! Each element's value for a colour is the mean over all its pixels of
//! that colour bilinearly interpolated from its own pixels
//! ([`crate::scene::PixelMap::interpolated`]): a weighted sum of the
//! colour's pixels, centred on the element as `T`'s row is (their plain
//! mean sits half a pixel off).

use crate::scene::Cells;

/// A colour channel of an RGB measurement, in the order arrays hold them.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize, utoipa::ToSchema,
)]
#[serde(rename_all = "lowercase")]
pub enum Colour {
    /// Red.
    Red,
    /// Green.
    Green,
    /// Blue.
    Blue,
}

impl Colour {
    /// Red, green, blue: the order of a measurement's channels and of an RGB image.
    pub const ALL: [Colour; 3] = [Colour::Red, Colour::Green, Colour::Blue];
}

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
        assert!(!r.and(BayerPattern::RG.cells(Colour::Blue)).in_row(0));
    }
}
