//! Captures a caller hands in as frame stacks (a user's TIFF files, NumPy
//! arrays from Python), measured the way the daemon measures its own.
//!
//! Why: `polnlos measure` and the Python bindings must turn the same frames
//! into the same `i` and variance, so both call [`measure_given`].

use super::{load, CaptureInfo, CaptureSource, FrameStack, MeasureError, Measurement, Units};
use crate::scene::{Frame, Scene};
use crate::transport::{Block, MemoryBudget, TransportError};

/// One capture's frames and the dark frames to subtract from their mean.
pub struct GivenCapture {
    /// What the capture was (pose, blocks, exposure, full scale).
    pub info: CaptureInfo,
    /// Its frames.
    pub stack: FrameStack,
    /// Dark frames (scene off, same exposure and region).
    pub dark: Option<FrameStack>,
}

impl GivenCapture {
    /// One capture named `name` (how errors and warnings name it) at `pose`
    /// through `channels`; without a dark, the warning says `how_to_dark`
    /// (the CLI's flag, the Python argument). Region and binning are not
    /// known: the frames must be the ones the pose's homography maps to.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        name: String,
        pose: String,
        channels: Vec<crate::scene::Channel>,
        stack: FrameStack,
        dark: Option<FrameStack>,
        full_scale: f64,
        exposure_us: f64,
        how_to_dark: &'static str,
    ) -> Self {
        Self {
            info: CaptureInfo {
                name,
                pose,
                channels,
                frames: stack.count,
                full_scale,
                exposure_us,
                region: None,
                binning: None,
                missing_dark: dark.is_none().then_some(how_to_dark),
                bayer: None,
            },
            stack,
            dark,
        }
    }
}

impl GivenCapture {
    /// The same capture from a colour camera's raw frames behind `pattern`.
    pub fn with_bayer(mut self, pattern: Option<super::colour::BayerPattern>) -> Self {
        self.info.bayer = pattern;
        self
    }
}

impl CaptureSource for GivenCapture {
    type Error = MeasureError;

    fn info(&self) -> CaptureInfo {
        self.info.clone()
    }

    /// The dark-subtracted mean, NaN at every pixel that reached full
    /// scale in a frame: its mean is only a lower bound, and its element is
    /// left out of the measurement (issue 38).
    fn mean(&self) -> Result<Frame, MeasureError> {
        let dark = match &self.dark {
            Some(d) => Some(d.mean_minus(None)?),
            None => None,
        };
        let mut mean = self.stack.mean_minus(dark.as_ref())?;
        if let Some(s) = self.stack.saturated_pixels() {
            for (p, &s) in mean.pixels.iter_mut().zip(s) {
                if s {
                    *p = f32::NAN;
                }
            }
        }
        Ok(mean)
    }

    /// The variance of the dark-subtracted mean: the frames' plus the dark's
    /// (MODEL.md `var_p`).
    fn variance(&self) -> Result<Option<Frame>, MeasureError> {
        let mut v = self.stack.variance_frame();
        let d = self.dark.as_ref().and_then(FrameStack::variance_frame);
        if let (Some(v), Some(d)) = (v.as_mut(), d) {
            if (d.width, d.height) != (v.width, v.height) {
                return Err(MeasureError::DarkSize {
                    dark: [d.width, d.height],
                    frames: [v.width, v.height],
                });
            }
            v.pixels
                .iter_mut()
                .zip(&d.pixels)
                .for_each(|(a, b)| *a += b);
        }
        Ok(v)
    }
}

/// The units a measurement is put in.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum UnitsWanted {
    /// Fractions of full scale per microsecond (for `calibrate wall`).
    Raw,
    /// Units of `T l`, divided by the bench's radiometric gain.
    Gain(f64),
    /// Units of `T l`, scaled so that the brightest element is about 1.
    Estimated,
}

/// A measurement from given captures, in the scene's block order.
pub struct Measured {
    /// `i` and its variance, each with the units applied (`None` for
    /// [`UnitsWanted::Raw`]): one grey measurement over every pixel, or,
    /// when every capture came from a colour camera, red, green and blue,
    /// each from its own pixels with its own estimated scale.
    pub channels: Vec<(Measurement, Option<Units>)>,
    /// The scene's blocks, in row order.
    pub blocks: Vec<Block>,
}

/// Why given captures could not be measured.
#[derive(Debug, thiserror::Error)]
pub enum GivenError {
    /// A capture does not fit the scene or cannot be read.
    #[error(transparent)]
    Measure(#[from] MeasureError),
    /// `T`, needed for the estimated units, could not be built.
    #[error(transparent)]
    Transport(#[from] TransportError),
    /// The estimated units could not be computed.
    #[error(transparent)]
    Solve(#[from] crate::solve::SolveError),
    /// The gain is not a positive number.
    #[error("gain {0}: must be a positive number")]
    Gain(f64),
}

/// Measures `captures` for `scene`: each capture read and checked
/// ([`load`]), the blocks stacked in the scene's order ([`super::assemble`]) and
/// put in the units asked for; `progress` hears how many columns of `T` are
/// built (only the estimated units need `T`). What the user should know (no
/// dark subtraction, estimated units) is added to `warnings`, failure or not.
pub fn measure_given(
    scene: &Scene,
    captures: &[GivenCapture],
    units: UnitsWanted,
    budget: MemoryBudget,
    progress: &(dyn Fn(usize) + Sync),
    warnings: &mut Vec<String>,
) -> Result<Measured, GivenError> {
    let mut all = measure_given_sets(
        scene,
        std::slice::from_ref(&captures),
        units,
        budget,
        progress,
        warnings,
    )?;
    // One set in, one measurement out.
    Ok(all.swap_remove(0))
}

/// [`measure_given`] of several sets of captures of the same blocks (the
/// colour planes of RGB frames), `T` built at most once for them all.
pub fn measure_given_sets(
    scene: &Scene,
    sets: &[&[GivenCapture]],
    units: UnitsWanted,
    budget: MemoryBudget,
    progress: &(dyn Fn(usize) + Sync),
    warnings: &mut Vec<String>,
) -> Result<Vec<Measured>, GivenError> {
    if let UnitsWanted::Gain(g) = units {
        if !(g.is_finite() && g > 0.0) {
            return Err(GivenError::Gain(g));
        }
    }
    let blocks = crate::transport::blocks_of(scene);
    // Every set measured first: a capture that does not fit is an error
    // before T is built.
    let mut measured = Vec::with_capacity(sets.len());
    for captures in sets {
        let loaded = captures
            .iter()
            .map(|c| load(scene, c, warnings))
            .collect::<Result<Vec<_>, _>>()?;
        let colours: Vec<Option<super::colour::Colour>> =
            match !loaded.is_empty() && loaded.iter().all(|c| c.bayer.is_some()) {
                true => super::colour::Colour::ALL.map(Some).to_vec(),
                false => vec![None],
            };
        let maps = super::PixelMaps::default();
        let channels = colours
            .into_iter()
            .map(|c| super::assemble_colour(scene, &blocks, &loaded, &maps, c))
            .collect::<Result<Vec<_>, _>>()?;
        let rows = channels[0].i.len();
        let missing = (0..rows)
            .filter(|&j| channels.iter().any(|m| m.i[j].is_nan()))
            .count();
        if missing > 0 {
            warnings.push(format!(
                "{missing} of {rows} wall elements were not measured (a pixel of theirs reached full scale in a frame; lower the exposure): they are written as NaN, and polnlos reconstruct leaves them out"
            ));
        }
        measured.push(channels);
    }
    // Only the estimated scale needs T, built once for every set and colour.
    let t = match units {
        UnitsWanted::Estimated => Some(crate::transport::build_with_progress(
            scene,
            budget,
            progress,
            Default::default(),
        )?),
        _ => None,
    };
    let in_units = |mut m: Measurement| -> Result<(Measurement, Option<Units>), GivenError> {
        let u = match (units, &t) {
            (UnitsWanted::Gain(g), _) => Some(Units::Calibrated(g)),
            (UnitsWanted::Estimated, Some(t)) => {
                // Estimated from the measured rows only.
                let mut known = m.clone();
                let missing = known.zero_unmeasured();
                match missing.is_empty() {
                    true => Some(Units::estimate(t, &m)?),
                    false => Some(Units::estimate(&t.with_rows_zeroed(&missing), &known)?),
                }
            }
            _ => None,
        };
        if let Some(u) = u {
            u.apply(&mut m);
        }
        Ok((m, u))
    };
    let mut out = Vec::with_capacity(sets.len());
    for channels in measured {
        out.push(Measured {
            channels: channels
                .into_iter()
                .map(&in_units)
                .collect::<Result<Vec<_>, _>>()?,
            blocks: blocks.clone(),
        });
    }
    let first = out.first().and_then(|m| m.channels.first());
    if let Some(w) = first.and_then(|(_, u)| *u).and_then(Units::note) {
        warnings.push(format!(
            "{w}; give the bench's radiometric gain for absolute units"
        ));
    }
    Ok(out)
}
