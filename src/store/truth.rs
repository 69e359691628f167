//! What a reconstruction is scored against: a test pattern's name, or an
//! image of the hidden scene as people store it (top row first).
//!
//! Why here: the request, the stored parameters, the worker and the truth
//! image's download read the same value.

use serde::{Deserialize, Serialize};

use crate::files::truth::{TopFirst, TruthError};
use crate::scene::Grid;
use crate::simulate::patterns::Pattern;

/// A known truth: `"letter"`, or `{"image": [[...], ...]}`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(untagged)]
pub enum Truth {
    /// A test pattern's name: `disk`, `bars`, `letter` or `flat`.
    Pattern(String),
    /// An image on the scene's grid.
    Image(TruthImage),
}

/// A truth image: its rows top first (row 0 the hidden plane's top, +v),
/// each row's pixels left to right (+u) as seen from in front of the plane.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct TruthImage {
    /// `[rows][columns]` of grey values, or `[rows][columns][3]` of red,
    /// green and blue; the scene grid's rows and columns (`nv` x `nu`),
    /// on the scale of the result (0 black, 1 the brightest the
    /// reconstruction recovers) for PSNR to mean as for a pattern.
    #[schema(min_items = 1)]
    pub image: Vec<Vec<Pixel>>,
}

/// One pixel of a truth image: a grey value, or one value a colour.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(untagged)]
pub enum Pixel {
    /// A grey value.
    Grey(f64),
    /// Red, green and blue.
    Colour(Vec<f64>),
}

impl Truth {
    /// The truth's channels on `grid` in its element order, `colours` of
    /// them (a grey truth is every colour's, a colour one against one
    /// channel its luma); `what` names it in an error.
    pub fn channels(
        &self,
        grid: Grid,
        colours: usize,
        what: &str,
    ) -> Result<Vec<Vec<f64>>, TruthError> {
        match self {
            Truth::Pattern(name) => match Pattern::from_name(name) {
                Some(p) => Ok(vec![p.render(grid); colours]),
                None => Err(TruthError::Pattern {
                    what: what.into(),
                    name: name.clone(),
                }),
            },
            Truth::Image(i) => i.top_first(what)?.on_grid(grid, colours, what),
        }
    }

    /// Checks the truth against `grid`: a known pattern, or an image of
    /// the grid's size with 1 or 3 values a pixel.
    pub fn check(&self, grid: Grid, what: &str) -> Result<(), TruthError> {
        let colours = match self {
            Truth::Image(i) if i.top_first(what)?.channels != 1 => 3,
            _ => 1,
        };
        self.channels(grid, colours, what).map(|_| ())
    }

    /// The pattern's name, when the truth is one.
    pub fn pattern(&self) -> Option<&str> {
        match self {
            Truth::Pattern(name) => Some(name),
            Truth::Image(_) => None,
        }
    }
}

impl From<&str> for Truth {
    fn from(name: &str) -> Self {
        Truth::Pattern(name.into())
    }
}

impl TruthImage {
    /// The image as values: every row as long as the first, every pixel
    /// alike (all grey, or all three colours).
    fn top_first(&self, what: &str) -> Result<TopFirst, TruthError> {
        let width = self.image.first().map_or(0, Vec::len);
        let channels = match self.image.first().and_then(|r| r.first()) {
            Some(Pixel::Colour(c)) => c.len(),
            _ => 1,
        };
        let mut data = Vec::with_capacity(self.image.len() * width * channels);
        for (row, pixels) in self.image.iter().enumerate() {
            if pixels.len() != width {
                return Err(TruthError::Ragged {
                    what: what.into(),
                    row,
                    len: pixels.len(),
                    width,
                });
            }
            for (col, p) in pixels.iter().enumerate() {
                match p {
                    Pixel::Grey(v) if channels == 1 => data.push(*v),
                    Pixel::Colour(c) if c.len() == channels && channels != 1 => {
                        data.extend_from_slice(c)
                    }
                    _ => {
                        return Err(TruthError::Mixed {
                            what: what.into(),
                            row,
                            col,
                        })
                    }
                }
            }
        }
        Ok(TopFirst {
            height: self.image.len(),
            width,
            channels,
            data,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(json: &str) -> Truth {
        serde_json::from_str(json).unwrap()
    }

    #[test]
    fn a_truth_is_a_pattern_name_or_an_image_top_row_first() {
        let grid = Grid { nu: 2, nv: 2 };
        assert_eq!(parse(r#""disk""#), Truth::Pattern("disk".into()));
        let grey = parse(r#"{"image": [[1, 0.5], [0, 0.25]]}"#);
        assert_eq!(
            grey.channels(grid, 1, "truth").unwrap(),
            vec![vec![0.0, 0.25, 1.0, 0.5]]
        );
        let rgb = parse(r#"{"image": [[[1, 0, 0], [0, 1, 0]], [[0, 0, 1], [1, 1, 1]]]}"#);
        assert_eq!(
            rgb.channels(grid, 3, "truth").unwrap()[2],
            vec![1.0, 1.0, 0.0, 0.0]
        );
        assert!(rgb.check(grid, "truth").is_ok());
        // Written back as it came.
        assert_eq!(serde_json::to_value(&grey).unwrap()["image"][0][1], 0.5);
    }

    #[test]
    fn a_wrong_truth_image_says_what_is_wrong() {
        let grid = Grid { nu: 2, nv: 2 };
        let err = |json: &str| parse(json).check(grid, "truth").unwrap_err().to_string();
        assert_eq!(
            err(r#"{"image": [[1, 0.5, 0]]}"#),
            "truth is 1 x 3 (rows x columns); the scene grid is 2 x 2: give the truth on the scene's grid, top row first"
        );
        assert!(err(r#"{"image": [[1, 0.5], [0]]}"#).contains("row 1 has 1 pixels"));
        assert!(err(r#"{"image": [[1, [0, 0, 0]], [0, 1]]}"#).contains("row 0, column 1"));
        assert!(
            err(r#"{"image": [[[1, 0], [0, 1]], [[1, 0], [0, 1]]]}"#).contains("2 values a pixel")
        );
        assert!(err(r#""cat""#).contains("\"cat\""));
    }
}
