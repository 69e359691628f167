//! A colour camera's balance: each colour's response to a neutral (white or
//! grey) field, relative to the colour that responds most.
//!
//! Why: one gain for every colour keeps the camera's own colour response (a
//! Bayer filter passes each colour differently), so a white object comes
//! out tinted. `T` is the same for every colour, so under a field of one
//! spectrum each colour's measurement is its own gain times one common
//! `T l` (docs/MODEL.md, "Problem": `i = T l`); the ratio of two
//! colours' sums over the wall is the ratio of their gains, whatever the
//! field's shape.

use serde::{Deserialize, Serialize};

use crate::scene::Colour;

/// A colour's response known to no better than this (relative standard
/// error, from the frames' noise) is refused: a 5 % error is a visible tint.
pub(crate) const MAX_RELATIVE_SIGMA: f64 = 0.02;

/// One colour's response to the field.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ColourResponse {
    /// The colour.
    pub colour: Colour,
    /// Its summed measurement over the strongest colour's: the factor a
    /// calibrated gain is multiplied by for this colour (1 for the strongest).
    pub ratio: f64,
    /// Standard error of `ratio`, from the frames' noise (0 when the
    /// measurement had no variance).
    pub sigma: f64,
}

/// Every colour's response, and the wall elements it was measured over.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ColourBalance {
    /// Red, green, blue, as the measurement's channels.
    pub colours: Vec<ColourResponse>,
    /// The colour that responds most (ratio 1): the one a scene's single
    /// calibrated gain is taken to be of.
    pub reference: Colour,
    /// Wall elements (rows) measured in every colour, over which the sums ran.
    pub rows: usize,
}

impl ColourBalance {
    /// The ratio of `colour`, if the balance has it.
    pub fn ratio(&self, colour: Colour) -> Option<f64> {
        self.colours
            .iter()
            .find(|c| c.colour == colour)
            .map(|c| c.ratio)
    }

    /// The gain `colour` is divided by when the scene's one gain is `gain`
    /// (the reference colour's): `gain` times its ratio, `gain` for a colour
    /// the balance does not have.
    pub fn gain(&self, colour: Colour, gain: f64) -> f64 {
        gain * self.ratio(colour).unwrap_or(1.0)
    }
}

/// Why a colour balance could not be measured.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ColourBalanceError {
    /// Fewer than two colours.
    #[error("a colour balance needs a colour measurement, and this one has {0} colour(s): was the capture taken with a colour (Bayer) camera?")]
    OneColour(usize),
    /// The colours have different numbers of rows.
    #[error("{colour:?} has {got} values where red has {want}")]
    Rows {
        /// The colour.
        colour: Colour,
        /// Its values.
        got: usize,
        /// Red's values.
        want: usize,
    },
    /// No row is measured in every colour.
    #[error("no wall element was measured in every colour (all are saturated or left out)")]
    NoCommonRow,
    /// A colour saw no light.
    #[error("{colour:?} received no light (its sum over the wall is {sum:.3e}): is the field lit, is the lens uncovered, were the dark frames taken with the field off?")]
    Dark {
        /// The colour.
        colour: Colour,
        /// Its sum over the common rows.
        sum: f64,
    },
    /// A colour's ratio is too noisy to calibrate with.
    #[error("{colour:?}'s response is known to only {percent:.1} % from the frames' noise (at most {limit:.1} % is taken): take more frames, a longer exposure or a brighter field")]
    Noisy {
        /// The colour.
        colour: Colour,
        /// Its relative standard error, percent.
        percent: f64,
        /// The limit, percent.
        limit: f64,
    },
}

/// One colour's measurement: the colour, one value per wall element (NaN:
/// not measured), and each value's variance when known.
pub(crate) type ColourValues<'a> = (Colour, &'a [f64], Option<&'a [f64]>);

/// Each colour's response from a measurement of a neutral field. Sums run
/// over the rows every colour measured.
pub(crate) fn balance(colours: &[ColourValues<'_>]) -> Result<ColourBalance, ColourBalanceError> {
    if colours.len() < 2 {
        return Err(ColourBalanceError::OneColour(colours.len()));
    }
    let n = colours[0].1.len();
    for (colour, values, var) in colours {
        for got in [Some(values.len()), var.map(<[f64]>::len)]
            .into_iter()
            .flatten()
        {
            if got != n {
                return Err(ColourBalanceError::Rows {
                    colour: *colour,
                    got,
                    want: n,
                });
            }
        }
    }
    let common: Vec<usize> = (0..n)
        .filter(|&k| colours.iter().all(|(_, v, _)| v[k].is_finite()))
        .collect();
    if common.is_empty() {
        return Err(ColourBalanceError::NoCommonRow);
    }
    // Each colour's sum and the variance of that sum.
    let sums: Vec<(f64, f64)> = colours
        .iter()
        .map(|(_, v, var)| {
            let s = common.iter().map(|&k| v[k]).sum::<f64>();
            let vs = var.map_or(0.0, |var| common.iter().map(|&k| var[k].max(0.0)).sum());
            (s, vs)
        })
        .collect();
    for ((colour, _, _), &(sum, _)) in colours.iter().zip(&sums) {
        if sum.is_nan() || sum <= 0.0 {
            return Err(ColourBalanceError::Dark {
                colour: *colour,
                sum,
            });
        }
    }
    let strongest = (0..sums.len())
        .max_by(|&a, &b| sums[a].0.total_cmp(&sums[b].0))
        .unwrap_or(0);
    let (sr, vr) = sums[strongest];
    let mut out = Vec::with_capacity(colours.len());
    for (k, ((colour, _, _), &(s, vs))) in colours.iter().zip(&sums).enumerate() {
        let ratio = s / sr;
        // First-order propagation; the reference's own ratio is exact.
        let rel = match k == strongest {
            true => 0.0,
            false => (vs / (s * s) + vr / (sr * sr)).sqrt(),
        };
        if rel > MAX_RELATIVE_SIGMA {
            return Err(ColourBalanceError::Noisy {
                colour: *colour,
                percent: 100.0 * rel,
                limit: 100.0 * MAX_RELATIVE_SIGMA,
            });
        }
        out.push(ColourResponse {
            colour: *colour,
            ratio,
            sigma: ratio * rel,
        });
    }
    Ok(ColourBalance {
        colours: out,
        reference: colours[strongest].0,
        rows: common.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A field of any shape seen through gains 0.55, 1, 0.7 gives those
    /// ratios; unmeasured rows are left out of every colour.
    #[test]
    fn the_ratios_are_the_gains_whatever_the_field() {
        let field: Vec<f64> = (0..50)
            .map(|k| 0.1 + (k as f64 * 0.37).sin().abs())
            .collect();
        let gains = [0.55, 1.0, 0.7];
        let mut ch: Vec<Vec<f64>> = gains
            .iter()
            .map(|g| field.iter().map(|f| g * f).collect())
            .collect();
        // Red's element 3 not measured; blue's element 3 a wild value that
        // must be left out with it.
        ch[0][3] = f64::NAN;
        ch[2][3] = 1e6;
        let var: Vec<f64> = vec![1e-8; 50];
        let input: Vec<ColourValues> = Colour::ALL
            .iter()
            .zip(&ch)
            .map(|(c, v)| (*c, v.as_slice(), Some(var.as_slice())))
            .collect();
        let b = balance(&input).unwrap();
        assert_eq!(b.reference, Colour::Green);
        assert_eq!(b.rows, 49);
        for (r, g) in b.colours.iter().zip(gains) {
            assert!((r.ratio - g).abs() < 1e-12, "{r:?}");
        }
        assert_eq!(b.colours[1].sigma, 0.0);
        assert!(b.colours[0].sigma > 0.0 && b.colours[0].sigma < 1e-3);
        assert_eq!(b.ratio(Colour::Blue), Some(b.colours[2].ratio));
        assert_eq!(b.gain(Colour::Red, 2.0), 2.0 * b.colours[0].ratio);
    }

    #[test]
    fn a_grey_a_dark_or_a_noisy_measurement_is_refused_naming_why() {
        let v = [1.0, 2.0];
        assert_eq!(
            balance(&[(Colour::Red, &v, None)]),
            Err(ColourBalanceError::OneColour(1))
        );
        let dark = [0.0, 0.0];
        assert!(matches!(
            balance(&[(Colour::Red, &v, None), (Colour::Blue, &dark, None)]),
            Err(ColourBalanceError::Dark {
                colour: Colour::Blue,
                ..
            })
        ));
        let noisy = [1.0, 1.0];
        let e = balance(&[(Colour::Red, &v, None), (Colour::Green, &v, Some(&noisy))]);
        assert!(matches!(e, Err(ColourBalanceError::Noisy { .. })), "{e:?}");
        assert!(e.unwrap_err().to_string().contains("take more frames"));
        let short = [1.0];
        assert!(matches!(
            balance(&[(Colour::Red, &v, None), (Colour::Green, &short, None)]),
            Err(ColourBalanceError::Rows {
                got: 1,
                want: 2,
                ..
            })
        ));
        let none = [f64::NAN, f64::NAN];
        assert_eq!(
            balance(&[(Colour::Red, &v, None), (Colour::Green, &none, None)]),
            Err(ColourBalanceError::NoCommonRow)
        );
    }
}
