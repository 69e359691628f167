//! A photograph's reconstruction: a real camera's unknown gain and ambient
//! light, and a data term blind to what the model cannot know
//! (docs/realphoto.md, a proposal beside MODEL.md Eq. 12).
//!
//! Why: a real photo carries ambient light and a smooth model error (the
//! wall's true reflectance, the screen's true lobe) that the raw-value data
//! term of Eq. 12 fits as if they were scene light: on Saunders et al.'s
//! chair photo that costs about 2 dB and 0.15 ZNCC. First differences of each
//! block's wall image cancel a constant background and most of a smooth
//! error; the unknown gain then only scales `l`, so `l >= 0` is solved
//! without the upper bound and scaled afterwards.
//!
//! The model is `i = g T l + b` per block and colour channel. Fitting
//! `||D (i - T x)||^2 + lambda TV(x)` over `x = g l >= 0` gives `x`; `g` is
//! the 99th percentile of `x` (the brightest scene element the data
//! resolves maps to 1) and `b` the block's mean of `i - T x`. λ comes from
//! the photo alone: the misfit of the non-negative least-squares fit (λ = 0)
//! is the model error plus noise, and λ is raised until the misfit grows by
//! the degrees of freedom the scene's unknowns had taken
//! (`M / (M - n)`), a discrepancy principle on the error the model leaves.

use std::sync::Arc;
use std::time::Instant;

use rayon::prelude::*;

use super::gram::{Gram, Normal};
use super::solvers::{largest_eigenvalue, symmetric, AdmmSettings, Solver, Warm};
use super::tv::gradient;
use super::{check_measurement, SolveError};
use crate::scene::{Scene, ShadowChoice, ShadowModel};
use crate::stop::Stop;
use crate::transport::Transport;

mod differences;
mod metrics;
mod model;
#[cfg(feature = "daemon")]
mod stream;

pub use differences::differences;
use differences::*;
pub use metrics::least_squares_misfit;
pub(crate) use metrics::PhotoMetrics;
pub(crate) use metrics::{
    difference_residuals, least_squares_misfits, noise_checks, photo_metrics,
};
pub(crate) use model::PhotoModel;
#[cfg(feature = "daemon")]
pub(crate) use stream::PhotoStream;

/// What a photo's data term fits.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize, clap::ValueEnum,
)]
#[serde(rename_all = "lowercase")]
pub enum DataTerm {
    /// `||i - g T l - b||^2` over the raw values (the background a constant
    /// per block, fitted with `l`).
    Values,
    /// `||D (i - T x)||^2`, `D` the first differences of each block's wall
    /// image along u and along v: blind to a constant background per block.
    Differences,
}

/// Percentile of `x` that the gain maps to 1 (robust against a few hot elements).
pub(crate) const GAIN_PERCENTILE: f64 = 0.99;
/// ADMM penalty in units of the largest eigenvalue of the data term's Gram:
/// fixed, so that one factorization serves every λ trial and channel.
const RHO_REL: f64 = 0.1;
/// λ is searched over `2 sigma sqrt(eig_max) x 10^[LOG_LO, LOG_HI]`, the
/// scale at which TV and the data term weigh alike (docs/realphoto.md).
const LOG_LO: f64 = -3.0;
const LOG_HI: f64 = 2.0;
/// Bisection steps on log λ (5 decades / 2^9: 0.01 decade).
const BISECTIONS: usize = 9;

/// How a photo is reconstructed; `Default` is the data-driven setting.
#[derive(Debug, Clone, Copy)]
pub struct PhotoSettings<'a> {
    /// What the data term fits.
    pub data_term: DataTerm,
    /// TV weight in the data term's units; `None`: the discrepancy rule.
    pub lambda: Option<f64>,
    /// ADMM iterations of the λ = 0 fit and of the final solve; each
    /// bisection step takes a third of them, warm-started.
    pub iterations: usize,
    /// Ends the solve early when raised.
    pub stop: Stop<'a>,
    /// Whether the photo's row and column order is checked ([`Orientation`]).
    pub orientation: OrientationCheck,
}

/// Whether a reconstruction checks the photo's orientation.
///
/// Why: a photo or an imported file can come in any row or column order,
/// while a camera capture through a calibrated homography has the order
/// the homography fixed, and the check costs four fits.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum OrientationCheck {
    /// Fit the photo as given and under each flip; warn when a flip fits
    /// clearly better (by more than 10 % of the misfit as given).
    #[default]
    Check,
    /// The orientation is known (a camera capture through its pose's
    /// homography): no check.
    Known,
}

impl Default for PhotoSettings<'_> {
    fn default() -> Self {
        Self {
            data_term: DataTerm::Differences,
            lambda: None,
            iterations: 150,
            stop: Stop::default(),
            orientation: OrientationCheck::Check,
        }
    }
}

/// One colour channel of a photo's reconstruction.
#[derive(Debug, Clone, serde::Serialize)]
pub struct PhotoChannel {
    /// `l = x / g` clipped to [0, 1], row-major on the scene grid.
    #[serde(skip)]
    pub image: Vec<f64>,
    /// `x = g l` in measurement units per unit of `T`.
    #[serde(skip)]
    pub x: Vec<f64>,
    /// Gain `g` that maps `x` to `l` (measurement units per unit of `T` at
    /// `l = 1`), as [`PhotoResult::gain_rule`] says it was set.
    pub gain: f64,
    /// This channel's own 99th percentile of `x`: the gain it would have
    /// alone (its brightest resolved element at 1).
    pub peak: f64,
    /// Share of the data term's energy `||D i||^2` that the λ = 0 fit
    /// explains.
    pub explained: f64,
    /// The most a fit of the unknowns to pure noise would explain
    /// (`unknowns / rows`): a channel at or below twice this carries no
    /// signal polnlos can tell from noise.
    pub noise_explains: f64,
    /// Whether the channel carries a signal ([`PhotoChannel::explained`]
    /// above twice [`PhotoChannel::noise_explains`]).
    pub informative: bool,
    /// Uncertainty of the gain: the bootstrap's root-mean-square error and
    /// the shift from the λ = 0 fit's gain, in quadrature (docs/realphoto.md).
    pub gain_sd: f64,
    /// Fitted ambient background per block (measurement units).
    pub background: Vec<f64>,
    /// Uncertainty of each block's background: the bootstrap's
    /// root-mean-square error and the shift from the λ = 0 fit's
    /// background, in quadrature (docs/realphoto.md).
    pub background_sd: Vec<f64>,
    /// TV weight used.
    pub lambda: f64,
    /// How λ was chosen.
    pub lambda_rule: String,
    /// Misfit of the data term at the result.
    pub misfit: f64,
    /// Misfit of the λ = 0 fit (model error plus noise).
    pub misfit_floor: f64,
    /// Rows of the data term that carry data.
    pub rows: usize,
    /// Unknowns (scene elements).
    pub unknowns: usize,
    /// RMS of the misfit the model leaves per row, `sqrt(floor / (rows - unknowns))`.
    pub residual_sd: f64,
    /// ADMM iterations, all trials included.
    pub iterations: usize,
    /// Seconds for this channel (the shared Gram excluded).
    pub seconds: f64,
    /// This channel alone against its truth, when one was given (the
    /// result's `metrics` are of every channel together).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub metrics: Option<super::metrics::Metrics>,
}

/// A flip of every block's wall image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Flip {
    /// As the file holds it.
    AsGiven,
    /// Mirrored along u (the photo's columns reversed).
    MirroredU,
    /// Mirrored along v (the photo's rows reversed).
    MirroredV,
    /// Both (turned by 180 degrees).
    Turned,
}

impl Flip {
    /// Every flip, in the order of [`Orientation::misfit`].
    pub const ALL: [Flip; 4] = [
        Flip::AsGiven,
        Flip::MirroredU,
        Flip::MirroredV,
        Flip::Turned,
    ];

    fn words(self) -> &'static str {
        match self {
            Flip::AsGiven => "as given",
            Flip::MirroredU => "mirrored along u (columns reversed)",
            Flip::MirroredV => "mirrored along v (rows reversed)",
            Flip::Turned => "turned by 180 degrees",
        }
    }

    /// `i` with every block's wall image flipped.
    pub fn apply(self, grid: crate::scene::Grid, i: &[f64]) -> Vec<f64> {
        let (nu, nv) = (grid.nu, grid.nv);
        let (fu, fv) = match self {
            Flip::AsGiven => (false, false),
            Flip::MirroredU => (true, false),
            Flip::MirroredV => (false, true),
            Flip::Turned => (true, true),
        };
        i.chunks(grid.count())
            .flat_map(|b| {
                (0..nv).flat_map(move |iv| {
                    (0..nu).map(move |iu| {
                        let (su, sv) = (
                            if fu { nu - 1 - iu } else { iu },
                            if fv { nv - 1 - iv } else { iv },
                        );
                        b[sv * nu + su]
                    })
                })
            })
            .collect()
    }
}

/// The misfit of a non-negative fit (λ = 0) of the photo's channels summed,
/// as given and under each [`Flip`]: the right orientation fits best.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct Orientation {
    /// Misfit per flip, in [`Flip::ALL`]'s order.
    pub misfit: [f64; 4],
    /// The flip that fits best by more than 10 % of the misfit as given:
    /// as given when none does.
    pub best: Flip,
}

/// How much lower than the photo as given a flip's misfit must be for the
/// flip to count as fitting better: 10 %.
///
/// Why: a photo whose orientation no flip decides (a symmetric scene, a
/// flat field) fits every flip alike up to rounding, and a tie is no
/// evidence; a wrong orientation fits several times worse (docs/realphoto.md).
pub(crate) const FLIP_MARGIN: f64 = 0.1;

/// The flip with the lowest misfit when it is below `(1 - FLIP_MARGIN)`
/// times the misfit as given; as given otherwise (and when a misfit is not
/// finite).
pub(crate) fn best_flip(misfit: &[f64; 4]) -> Flip {
    let lowest = (0..4)
        .min_by(|&a, &b| misfit[a].total_cmp(&misfit[b]))
        .unwrap_or(0);
    let clear = misfit[lowest] < (1.0 - FLIP_MARGIN) * misfit[0];
    match clear && misfit.iter().all(|m| m.is_finite()) {
        true => Flip::ALL[lowest],
        false => Flip::AsGiven,
    }
}

impl PhotoChannel {
    /// This fit of a photo divided by `s` as the fit of the photo itself:
    /// `x`, gains and backgrounds times `s`, λ times `s` (TV is linear in
    /// `x`), misfits times `s^2`; `l` and the shares are unchanged.
    fn rescale(&mut self, s: f64) {
        self.x.iter_mut().for_each(|v| *v *= s);
        self.gain *= s;
        self.peak *= s;
        self.gain_sd *= s;
        self.background.iter_mut().for_each(|v| *v *= s);
        self.background_sd.iter_mut().for_each(|v| *v *= s);
        self.lambda *= s;
        self.misfit *= s * s;
        self.misfit_floor *= s * s;
        self.residual_sd *= s;
    }
}

/// The root mean square of `channels`' values, one not finite (not
/// measured) counted as 0; 1 when it is 0 or there is no value.
fn rms(channels: &[Vec<f64>]) -> f64 {
    let (sum, n) = channels.iter().flatten().fold((0.0, 0usize), |(s, n), v| {
        (s + if v.is_finite() { v * v } else { 0.0 }, n + 1)
    });
    let r = (sum / n.max(1) as f64).sqrt();
    match r.is_finite() && r > 0.0 {
        true => r,
        false => 1.0,
    }
}

/// `x / gain` clipped to [0, 1] (all 0 for a gain that is not positive).
fn scaled(x: &[f64], gain: f64) -> Vec<f64> {
    x.iter()
        .map(|v| match gain > 0.0 {
            true => (v / gain).clamp(0.0, 1.0),
            false => 0.0,
        })
        .collect()
}

/// How far above what noise alone explains a channel's fit must reach to
/// count as signal ([`PhotoChannel::informative`]).
const SIGNAL_MARGIN: f64 = 2.0;

/// A photo's reconstruction, every channel, and what it cost.
#[derive(Debug, Clone, serde::Serialize)]
pub struct PhotoResult {
    /// The data term fitted.
    pub data_term: DataTerm,
    /// Each channel's fit, in the measurement's channel order.
    pub channels: Vec<PhotoChannel>,
    /// How the channels' gains were set (`balance`).
    pub gain_rule: String,
    /// Rows of `T` that were not measured (NaN in the measurement), left out.
    pub unmeasured_rows: usize,
    /// Against the truth, when one was given.
    pub metrics: Option<PhotoMetrics>,
    /// How the photo fits as given and flipped (a photo in the wrong row or
    /// column order still correlates with `T l`, and reconstructs a mirrored
    /// scene); null where the orientation is known ([`OrientationCheck::Known`]).
    pub orientation: Option<Orientation>,
    /// What is wrong, in words (empty when nothing is).
    pub warnings: Vec<String>,
    /// Seconds to form the data term's matrix and Gram (once for all channels).
    pub model_seconds: f64,
    /// Seconds for the channels (solved in parallel).
    pub solve_seconds: f64,
}

/// A photo's reconstruction as `report.json` holds it, the same from
/// `polnlos reconstruct --photo` and the daemon: the scene, the radiometry
/// and why, what `T` cost, and the fit.
#[derive(Debug, Clone, serde::Serialize)]
pub struct PhotoReport {
    /// Scene name.
    pub scene: String,
    /// Fitted, and why.
    pub radiometry: super::radiometry::RadiometryChoice,
    /// Seconds to build (or read) `T`.
    pub transport_seconds: f64,
    /// Where `T` came from: `hit` (the cache), `stored` or `built` (the
    /// CLI's cache; absent in the daemon, which keeps `T` per scene).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub transport_cache: Option<&'static str>,
    /// Point or area shadows, and why (docs/realphoto.md, "Which
    /// shadows"); absent where the daemon used its scene's `T` as built.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub shadows: Option<crate::scene::ShadowChoice>,
    /// Seconds in all.
    pub total_seconds: f64,
    /// The fit.
    #[serde(flatten)]
    pub result: PhotoResult,
}

/// Reconstructs every channel of a photo taken through `t` with one data
/// term, one Gram and one penalty; `truth` (channel by channel on the scene
/// grid) adds the metrics.
///
/// A row that is not finite in any channel was not measured (a saturated
/// element, or NaN in a file): it is left out of every channel's data term.
/// Every channel is scaled by one gain (`balance`).
pub fn reconstruct_photo(
    t: &Transport,
    channels: &[Vec<f64>],
    truth: Option<&[Vec<f64>]>,
    settings: &PhotoSettings<'_>,
) -> Result<PhotoResult, SolveError> {
    reconstruct_photo_with(t, None, channels, truth, settings)
}

/// The rows of `t` not finite in some channel (not measured), after
/// checking each channel has one value per row.
fn missing_rows(t: &Transport, channels: &[Vec<f64>]) -> Result<Vec<usize>, SolveError> {
    for c in channels {
        if c.len() != t.rows() {
            return Err(SolveError::Length {
                expected: t.rows(),
                got: c.len(),
            });
        }
    }
    Ok((0..t.rows())
        .filter(|&j| channels.iter().any(|c| !c[j].is_finite()))
        .collect())
}

/// [`reconstruct_photo`] on `model` when the shadow choice already formed
/// it for `t` and these channels' unmeasured rows ([`PhotoTransport`]).
fn reconstruct_photo_with(
    t: &Transport,
    model: Option<&PhotoModel>,
    channels: &[Vec<f64>],
    truth: Option<&[Vec<f64>]>,
    settings: &PhotoSettings<'_>,
) -> Result<PhotoResult, SolveError> {
    let missing = missing_rows(t, channels)?;
    // The fit in units of the photo's own RMS value: ADMM's absolute
    // tolerance then means the same whatever the photo's units (a camera's
    // fractions of full scale per µs, DN, an imported file's), so one photo
    // in other units gives the same image; every number is given back in
    // the photo's units. A value not measured is 0 (its rows are masked).
    let unit = rms(channels);
    let channels: Vec<Vec<f64>> = channels
        .iter()
        .map(|c| {
            c.iter()
                .map(|v| if v.is_finite() { v / unit } else { 0.0 })
                .collect()
        })
        .collect();
    let settings = &PhotoSettings {
        lambda: settings.lambda.map(|l| l / unit),
        ..*settings
    };
    let formed;
    let model = match model {
        Some(m) if m.fits(t, settings.data_term, &missing) => m,
        _ => {
            formed =
                PhotoModel::with_missing_until(t, settings.data_term, &missing, settings.stop)?;
            &formed
        }
    };
    let start = Instant::now();
    let orientation = match settings.orientation {
        OrientationCheck::Check => {
            let mut o = model.orientation(t, &channels, settings)?;
            o.misfit.iter_mut().for_each(|m| *m *= unit * unit);
            Some(o)
        }
        OrientationCheck::Known => None,
    };
    let mut warnings: Vec<String> = super::unmeasured_warning(&missing, t.rows())
        .into_iter()
        .chain(orientation.as_ref().and_then(flip_warning))
        .collect();
    let mut fits = channels
        .par_iter()
        .map(|i| model.channel(t, i, settings))
        .collect::<Result<Vec<_>, _>>()?;
    fits.iter_mut().for_each(|f| f.rescale(unit));
    let gain_rule = balance(&mut fits, &mut warnings);
    for (fit, truth) in fits.iter_mut().zip(truth.unwrap_or_default()) {
        fit.metrics = Some(super::metrics::compare(t.scene_grid(), truth, &fit.image));
    }
    let solve_seconds = start.elapsed().as_secs_f64();
    let metrics = truth.map(|truth| {
        let images: Vec<Vec<f64>> = fits.iter().map(|c| c.image.clone()).collect();
        photo_metrics(t.scene_grid(), truth, &images)
    });
    Ok(PhotoResult {
        data_term: settings.data_term,
        channels: fits,
        gain_rule,
        unmeasured_rows: missing.len(),
        metrics,
        orientation,
        warnings,
        model_seconds: model.seconds,
        solve_seconds,
    })
}

/// The warning that a flip fits the photo clearly better, if one does.
fn flip_warning(o: &Orientation) -> Option<String> {
    (o.best != Flip::AsGiven).then(|| {
        format!(
            "the photo fits T better {} (misfit {:.3} of the one as given, below the {:.2} that counts as better): check its row order and the scene's wall u_axis and normal (docs/realphoto.md, \"Orientation\")",
            o.best.words(),
            o.misfit[o.best as usize] / o.misfit[0],
            1.0 - FLIP_MARGIN
        )
    })
}

/// Sets each channel's gain: an informative channel's own
/// [`PhotoChannel::peak`] (its brightest resolved element is white), a
/// channel noise alone could explain the brightest informative channel's
/// (so it comes back as the little it is, not stretched to full scale), and
/// flags the latter. Returns the rule in words.
///
/// Why: a channel's gain and its scene's colour are one unknown
/// (`g_c l_c`), so a photo's colour balance can only be assumed; the data
/// tell a channel's gain only where the channel carries a signal, and a
/// signal-free channel stretched to its own peak turns black into white.
pub(crate) fn balance(fits: &mut [PhotoChannel], warnings: &mut Vec<String>) -> String {
    let informative = fits.iter().any(|c| c.informative);
    let peaks: Vec<f64> = fits.iter().map(|c| c.peak).collect();
    let flags: Vec<bool> = fits.iter().map(|c| c.informative).collect();
    let (who, gains) = balanced_gains(&peaks, &flags);
    let gain_sd = fits.get(who).map_or(0.0, |c| c.gain_sd);
    let many = fits.len() > 1;
    let mut flagged = Vec::new();
    for (k, c) in fits.iter_mut().enumerate() {
        if c.informative {
            continue;
        }
        flagged.push(k);
        if many {
            c.gain = gains[k];
            c.gain_sd = gain_sd;
            c.image = scaled(&c.x, c.gain);
        }
        warnings.push(format!(
            "channel {k}: its fit explains {:.2} % of its data, no more than noise alone could ({:.2} %): it carries no signal polnlos can tell from noise{}",
            100.0 * c.explained,
            100.0 * c.noise_explains,
            match (many, informative) {
                (true, true) => format!("; it is shown at channel {who}'s gain, not stretched to its own peak"),
                (true, false) => format!("; every channel is shown at channel {who}'s gain"),
                (false, _) => String::new(),
            }
        ));
    }
    match (many, flagged.is_empty()) {
        (false, _) => "the 99th percentile of x".to_string(),
        (true, true) => "each channel's own 99th percentile of x: every channel carries a signal, and its brightest resolved element is taken as white (white-patch balance; a calibrated gain per channel replaces it)".to_string(),
        (true, false) => format!(
            "each informative channel's own 99th percentile of x (white-patch balance); channel(s) {flagged:?}, which carry no signal, at channel {who}'s"
        ),
    }
}

/// `balance`'s rule: the reference channel (the informative channel
/// with the largest peak, or the channel with the largest peak when none is
/// informative) and each channel's gain from its `peaks` and whether it is
/// `informative`: its own peak, or the reference's for a channel without
/// signal among several.
pub(super) fn balanced_gains(peaks: &[f64], informative: &[bool]) -> (usize, Vec<f64>) {
    let any = informative.iter().any(|&b| b);
    let who = (0..peaks.len())
        .filter(|&k| informative.get(k) == Some(&true) || !any)
        .max_by(|&a, &b| peaks[a].total_cmp(&peaks[b]))
        .unwrap_or(0);
    let many = peaks.len() > 1;
    let gains = peaks
        .iter()
        .zip(informative)
        .map(|(&p, &i)| match i || !many {
            true => p,
            false => peaks[who],
        })
        .collect();
    (who, gains)
}

/// Settles a shadow choice the scene left `open` ([`crate::scene::Scene::shadow_choice`])
/// from the photo: the model whose `T` fits the photo's channels (summed)
/// better at λ = 0, non-negative and blind to gain and background, the
/// misfit [`PhotoModel::floor_misfit`] gives; `point` and `area` are the
/// scene's `T` with each. Returns the choice and the chosen `T`'s data-term
/// model (formed for the photo's unmeasured rows), which the reconstruction
/// then reuses.
///
/// Why: MODEL.md's point sources define the reference benches, but a real
/// screen behind a near occluder casts a penumbra: on a held-out photo
/// point shadows gave ZNCC 0.60 and area shadows 0.84; the misfit says
/// which the photo shows without a truth (docs/realphoto.md, "Which shadows").
fn pick_shadows(
    point: &Transport,
    area: &Transport,
    channels: &[Vec<f64>],
    settings: &PhotoSettings<'_>,
    choice: ShadowChoice,
) -> Result<(ShadowChoice, PhotoModel), SolveError> {
    let missing = missing_rows(point, channels)?;
    // An element not measured (NaN) is left out, as the reconstruction
    // leaves it out.
    let mut sum = vec![0.0; point.rows()];
    for c in channels {
        sum.iter_mut()
            .zip(c)
            .filter(|(_, v)| v.is_finite())
            .for_each(|(s, v)| *s += v);
    }
    let fit = |t: &Transport| {
        let model = PhotoModel::with_missing_until(t, settings.data_term, &missing, settings.stop)?;
        model.floor_misfit(t, &sum, settings).map(|m| (m, model))
    };
    let (p, a) = rayon::join(|| fit(point), || fit(area));
    let ((mp, point_model), (ma, area_model)) = (p?, a?);
    let (model, kept) = match ma < mp {
        true => (ShadowModel::Area, area_model),
        false => (ShadowModel::Point, point_model),
    };
    let penumbra = choice.penumbra.map_or(String::new(), |w| {
        format!("a scene cell's penumbra spans {w:.2} wall samples; ")
    });
    Ok((
        ShadowChoice {
            model,
            reason: format!(
                "{penumbra}the photo's λ = 0 misfit is {mp:.4e} with point shadows and {ma:.4e} with area shadows: {}",
                model.name()
            ),
            open: false,
            misfit: Some([mp, ma]),
            ..choice
        },
        kept,
    ))
}

/// The `T` a photo is reconstructed with, the scene's shadow choice, and
/// the data term's model when making the choice formed it.
pub struct PhotoTransport<T> {
    /// `T` with the chosen shadows.
    pub t: T,
    /// The choice and its reason.
    pub shadows: ShadowChoice,
    model: Option<PhotoModel>,
}

impl<T: std::ops::Deref<Target = Transport>> PhotoTransport<T> {
    /// Whether the photo chose area shadows where the scene left the choice
    /// open (the model is formed only then): `t` is then the area-shadow
    /// `T`, not the scene's own.
    pub fn chose_area(&self) -> bool {
        self.model.is_some() && self.shadows.model == ShadowModel::Area
    }

    /// [`reconstruct_photo`] of `channels` with this `T`, on the model the
    /// shadow choice formed when it fits them.
    pub fn reconstruct(
        &self,
        channels: &[Vec<f64>],
        truth: Option<&[Vec<f64>]>,
        settings: &PhotoSettings<'_>,
    ) -> Result<PhotoResult, SolveError> {
        reconstruct_photo_with(&self.t, self.model.as_ref(), channels, truth, settings)
    }
}

/// The `T` a photo is reconstructed with, and the shadow model's choice:
/// `point` (the scene's own `T`) where the scene fixes its shadows, else
/// whichever of it and `area()` (the area-shadow `T`, made only then)
/// explains the photo better (`PhotoModel::floor_misfit` of each).
///
/// Why one function: the CLI's `--photo`, the daemon's fitted
/// reconstruction and Python each get their `T`s their own way (a file
/// cache, the daemon's scene cache, a build) and must choose alike.
pub fn photo_transport<T, E>(
    scene: &Scene,
    point: T,
    area: impl FnOnce() -> Result<T, E>,
    channels: &[Vec<f64>],
    settings: &PhotoSettings<'_>,
) -> Result<PhotoTransport<T>, E>
where
    T: std::ops::Deref<Target = Transport>,
    E: From<SolveError>,
{
    let choice = scene.shadow_choice();
    if !choice.open {
        return Ok(PhotoTransport {
            t: point,
            shadows: choice,
            model: None,
        });
    }
    let area = area()?;
    let (shadows, model) = pick_shadows(&point, &area, channels, settings, choice)?;
    let t = match shadows.model {
        ShadowModel::Area => area,
        _ => point,
    };
    Ok(PhotoTransport {
        t,
        shadows,
        model: Some(model),
    })
}

/// Why a measurement array is not one polnlos can split into channels.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ChannelsError {
    /// A shape that is neither `[rows]` nor `[rows, C]`.
    #[error("shape {shape:?} is neither [{rows}] nor [{rows}, C] with C from 1 to 4 (one row per row of T, one column per colour channel)")]
    Shape {
        /// The array's shape.
        shape: Vec<usize>,
        /// The rows of `T`.
        rows: usize,
    },
    /// Fewer or more values than the shape says.
    #[error("holds {values} values where its shape says {expected}")]
    Count {
        /// Values in the array.
        values: usize,
        /// Values its shape gives.
        expected: usize,
    },
    /// An infinite value (NaN is the only mark of a row not measured).
    #[error("holds the infinite value {0} (NaN marks a row that was not measured)")]
    Infinite(f64),
}

/// The channels of a measurement array: `[rows]` is one channel, `[rows, C]`
/// (C from 1 to 4, interleaved as NumPy stores it) is C channels that share
/// one `T` (a colour photo's R, G, B); NaN marks a row that was not measured.
pub fn split_channels(
    shape: &[usize],
    data: &[f64],
    rows: usize,
) -> Result<Vec<Vec<f64>>, ChannelsError> {
    let c = match shape {
        [n] if *n == rows => 1,
        [n, c] if *n == rows && (1..=4).contains(c) => *c,
        s => {
            return Err(ChannelsError::Shape {
                shape: s.to_vec(),
                rows,
            })
        }
    };
    if data.len() != rows * c {
        return Err(ChannelsError::Count {
            values: data.len(),
            expected: rows * c,
        });
    }
    if let Some(&v) = data.iter().find(|v| v.is_infinite()) {
        return Err(ChannelsError::Infinite(v));
    }
    Ok((0..c)
        .map(|ch| data.iter().skip(ch).step_by(c).copied().collect())
        .collect())
}

/// The `p` quantile of `x` (nearest rank); 0 for an empty `x`.
fn percentile(x: &[f64], p: f64) -> f64 {
    if x.is_empty() {
        return 0.0;
    }
    let mut v = x.to_vec();
    v.sort_by(f64::total_cmp);
    let k = ((p * (v.len() - 1) as f64).round() as usize).min(v.len() - 1);
    v[k]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Grid;
    use crate::transport::Block;

    /// One block of smooth bumps: scene element `k` lights the wall
    /// around its own spot (`spacing` wall elements apart) with a Lorentzian
    /// of `width`.
    fn bumps(wall: Grid, scene: Grid, spacing: f64, width: f64) -> Transport {
        transport(wall, scene, 1, |j, k| {
            let (u, v) = ((j % wall.nu) as f64, (j / wall.nu) as f64);
            let (su, sv) = (
                (k % scene.nu) as f64 * spacing,
                (k / scene.nu) as f64 * spacing,
            );
            1.0 / (1.0 + width * ((u - su).powi(2) + (v - sv).powi(2)))
        })
    }

    pub(super) fn transport(
        rows_grid: Grid,
        scene: Grid,
        blocks: usize,
        f: impl Fn(usize, usize) -> f64,
    ) -> Transport {
        let rows = blocks * rows_grid.count();
        let cols = scene.count();
        let data = (0..cols)
            .flat_map(|k| (0..rows).map(move |j| (j, k)))
            .map(|(j, k)| f(j, k))
            .collect();
        let block = Block {
            pose: "A".into(),
            channel: crate::scene::Channel::None,
        };
        Transport::from_col_major(rows, cols, data, vec![block; blocks], rows_grid, scene)
    }

    #[test]
    fn a_flip_counts_as_better_only_past_the_margin() {
        // The tie of a camera capture: rounding, not evidence.
        let tie = [1.0, 1.0, 0.999_999_999_999_992_3, 1.0];
        assert_eq!(best_flip(&tie), Flip::AsGiven);
        // 9 % lower is inside the margin, 11 % past it.
        assert_eq!(best_flip(&[1.0, 0.91, 1.2, 1.3]), Flip::AsGiven);
        assert_eq!(best_flip(&[1.0, 0.89, 1.2, 1.3]), Flip::MirroredU);
        assert_eq!(best_flip(&[4.0, 3.0, 1.0, 2.0]), Flip::MirroredV);
        assert_eq!(best_flip(&[1.0, f64::NAN, 0.1, 1.0]), Flip::AsGiven);
        let o = Orientation {
            misfit: [4.0, 3.0, 1.0, 2.0],
            best: Flip::MirroredV,
        };
        let w = flip_warning(&o).expect("a warning");
        assert!(
            w.contains("misfit 0.250 of the one as given, below the 0.90"),
            "{w}"
        );
        let tied = Orientation {
            misfit: tie,
            best: best_flip(&tie),
        };
        assert_eq!(flip_warning(&tied), None);
    }

    #[test]
    fn flips_reverse_columns_rows_or_both_in_every_block() {
        let g = Grid { nu: 3, nv: 2 };
        let i: Vec<f64> = (0..12).map(f64::from).collect();
        assert_eq!(Flip::AsGiven.apply(g, &i), i);
        assert_eq!(
            Flip::MirroredU.apply(g, &i),
            [2.0, 1.0, 0.0, 5.0, 4.0, 3.0, 8.0, 7.0, 6.0, 11.0, 10.0, 9.0]
        );
        assert_eq!(
            Flip::MirroredV.apply(g, &i),
            [3.0, 4.0, 5.0, 0.0, 1.0, 2.0, 9.0, 10.0, 11.0, 6.0, 7.0, 8.0]
        );
        for f in Flip::ALL {
            assert_eq!(f.apply(g, &f.apply(g, &i)), i, "{f:?}");
        }
    }

    #[test]
    fn channels_are_split_from_rows_or_rows_by_colours() {
        let one = split_channels(&[3], &[1.0, 2.0, 3.0], 3).unwrap();
        assert_eq!(one, vec![vec![1.0, 2.0, 3.0]]);
        let rgb = split_channels(&[2, 3], &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0], 2).unwrap();
        assert_eq!(rgb, vec![vec![1.0, 4.0], vec![2.0, 5.0], vec![3.0, 6.0]]);
        assert!(split_channels(&[2, 5], &[0.0; 10], 2).is_err());
        assert!(split_channels(&[4], &[0.0; 4], 3).is_err());
        // NaN is a row not measured; an infinity is refused.
        assert!(split_channels(&[2], &[0.0, f64::NAN], 2).unwrap()[0][1].is_nan());
        assert!(split_channels(&[2], &[0.0, f64::INFINITY], 2)
            .unwrap_err()
            .to_string()
            .contains("infinite"));
    }

    #[test]
    fn the_affine_psnr_forgives_gain_and_offset_only() {
        let g = Grid { nu: 8, nv: 8 };
        let truth: Vec<f64> = (0..64).map(|k| ((k * 37) % 11) as f64 / 10.0).collect();
        let scaled: Vec<f64> = truth.iter().map(|v| 0.3 * v + 0.2).collect();
        let m = photo_metrics(g, std::slice::from_ref(&truth), &[scaled]);
        assert!(m.psnr_affine_db > 100.0 && m.psnr_db < 20.0, "{m:?}");
        assert!((m.zncc - 1.0).abs() < 1e-12);
    }

    #[test]
    fn differences_of_t_are_the_differences_of_each_column_per_block() {
        let (wall, scene) = (Grid { nu: 3, nv: 2 }, Grid { nu: 2, nv: 1 });
        let t = transport(wall, scene, 2, |j, k| (j * j + 3 * k) as f64);
        let d = differences(&t);
        assert_eq!((d.rows(), d.cols(), d.blocks().len()), (24, 2, 4));
        for k in 0..2 {
            let want = difference_values(&t, t.col(k));
            assert_eq!(d.col(k), &want[..]);
        }
        // Block 1 (rows 6..12 of T), element (iu 1, iv 0): u-difference
        // T[8] - T[7] and v-difference T[10] - T[7].
        let col = t.col(1);
        assert_eq!(d.get(12 + 1, 1), col[8] - col[7]);
        assert_eq!(d.get(12 + 6 + 1, 1), col[10] - col[7]);
        assert_eq!(difference_rows(&t), 2 * (2 * 2 + 3));
    }

    #[test]
    fn a_background_per_block_drops_out_of_the_differences() {
        let t = transport(Grid { nu: 4, nv: 4 }, Grid { nu: 1, nv: 1 }, 2, |j, _| {
            (j as f64).sin()
        });
        let i: Vec<f64> = t.col(0).iter().map(|v| 3.0 * v).collect();
        let shifted: Vec<f64> = i
            .iter()
            .enumerate()
            .map(|(j, v)| v + if j < 16 { 5.0 } else { -2.0 })
            .collect();
        let (a, b) = (difference_values(&t, &i), difference_values(&t, &shifted));
        assert!(
            a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-12),
            "{a:?} {b:?}"
        );
        assert!(a.iter().any(|x| x.abs() > 0.1));
    }

    #[test]
    fn a_photo_with_gain_and_background_gives_them_back() {
        // A 12x12 wall, a 3x3 scene, one block; smooth positive columns.
        let (wall, scene) = (Grid { nu: 12, nv: 12 }, Grid { nu: 3, nv: 3 });
        let t = bumps(wall, scene, 5.0, 0.05);
        let l = [0.2, 1.0, 0.0, 0.5, 0.7, 0.1, 0.0, 0.3, 0.9];
        let (g, b) = (40.0, 7.5);
        let i: Vec<f64> = t.apply(&l).iter().map(|v| g * v + b).collect();
        // Both data terms find the background; the differences also give x = g l.
        for term in [DataTerm::Differences, DataTerm::Values] {
            let settings = PhotoSettings {
                lambda: Some(0.0),
                iterations: 3000,
                ..Default::default()
            };
            let r = PhotoModel::new(&t, term)
                .channel(&t, &i, &settings)
                .unwrap();
            if term == DataTerm::Differences {
                for (x, want) in r.x.iter().zip(&l) {
                    assert!((x - g * want).abs() < 0.05 * g, "{:?}", r.x);
                }
            }
            assert!(
                (r.background[0] - b).abs() < 0.05,
                "{term:?}: {:?}",
                r.background
            );
        }
    }

    /// `g T l + b` with Gaussian noise of `sd`.
    fn noisy(t: &Transport, l: &[f64], sd: f64, seed: u64) -> Vec<f64> {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let noise = Normal::new(0.0, sd).expect("a positive sd");
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        t.apply(l)
            .iter()
            .map(|v| 40.0 * v + 7.5 + noise.sample(&mut rng))
            .collect()
    }

    #[test]
    fn the_model_check_is_one_for_the_model_s_own_photo_and_more_for_another_model_s() {
        // A 40x40 wall, a 6x6 scene of smooth bumps.
        let (wall, scene) = (Grid { nu: 40, nv: 40 }, Grid { nu: 6, nv: 6 });
        let t = bumps(wall, scene, 7.0, 0.05);
        let l: Vec<f64> = (0..36).map(|k| ((k * 7) % 11) as f64 / 10.0).collect();
        let sd = 0.05;
        let own = noisy(&t, &l, sd, 3);
        // The same scene through bumps a fifth wider: another model's photo.
        let other = noisy(&bumps(wall, scene, 7.0, 0.04), &l, sd, 4);
        let photos = [own, other];
        let ratio =
            |c: &metrics::NoiseCheck| c.misfit / c.noise_misfit.expect("a 40x40 wall is enough");
        // The noise from the residual's roughness. Measured: the model
        // check 0.990 for the model's own photo, 4.03 for the other's,
        // whose residual keeps some of the other model's bumps, so that its
        // noise reads too high (given, below: 0.963 and 16.2).
        let rough = noise_checks(&t, DataTerm::Differences, &photos, None).unwrap();
        assert!((ratio(&rough[0]) - 1.0).abs() < 0.06, "{rough:?}");
        assert!(ratio(&rough[1]) > 1.5, "{rough:?}");
        // The noise given: the same for the own photo, more for the other's.
        let variance = vec![vec![sd * sd; t.rows()]; 2];
        let given = noise_checks(&t, DataTerm::Differences, &photos, Some(&variance)).unwrap();
        assert!((ratio(&given[0]) - 1.0).abs() < 0.06, "{given:?}");
        assert!(ratio(&given[1]) > ratio(&rough[1]), "{given:?}");
        assert_eq!(given[0].misfit, rough[0].misfit);
        // A variance per channel, each one per row and >= 0.
        assert!(noise_checks(&t, DataTerm::Differences, &photos, Some(&variance[..1])).is_err());
        let negative = vec![vec![-1.0; t.rows()]; 2];
        assert!(noise_checks(&t, DataTerm::Differences, &photos, Some(&negative)).is_err());
        // The misfit is least_squares_misfits' own.
        let misfits =
            least_squares_misfits(&t, DataTerm::Differences, &[noisy(&t, &l, sd, 3)]).unwrap();
        assert_eq!(misfits[0], rough[0].misfit);
    }

    #[test]
    fn the_automatic_lambda_lies_inside_its_bracket_and_bad_settings_are_errors() {
        let (wall, scene) = (Grid { nu: 10, nv: 10 }, Grid { nu: 4, nv: 4 });
        let t = bumps(wall, scene, 3.0, 0.1);
        let l: Vec<f64> = (0..16)
            .map(|k| if k % 5 == 0 { 1.0 } else { 0.2 })
            .collect();
        let i: Vec<f64> = t
            .apply(&l)
            .iter()
            .enumerate()
            .map(|(j, v)| v + 0.01 * ((j * 7919 % 13) as f64 - 6.0))
            .collect();
        let model = PhotoModel::new(&t, DataTerm::Differences);
        let r = model.channel(&t, &i, &PhotoSettings::default()).unwrap();
        assert!(r.lambda > 0.0 && r.lambda.is_finite());
        assert!(
            r.misfit >= r.misfit_floor * 0.99,
            "{} < {}",
            r.misfit,
            r.misfit_floor
        );
        assert!(r.image.iter().all(|v| (0.0..=1.0).contains(v)));
        let bad = PhotoSettings {
            iterations: 0,
            ..Default::default()
        };
        assert!(model.channel(&t, &i, &bad).is_err());
        assert!(model
            .channel(&t, &i[1..], &PhotoSettings::default())
            .is_err());
    }

    #[test]
    fn an_unmeasured_row_leaves_every_difference_that_touches_it_out() {
        // A 4x3 wall, a 2x2 scene; one element of the second block lost.
        let (wall, scene) = (Grid { nu: 4, nv: 3 }, Grid { nu: 2, nv: 2 });
        let t = transport(wall, scene, 2, |j, k| 1.0 + ((j * 7 + k * 3) % 5) as f64);
        let l = [0.5, 1.0, 0.2, 0.8];
        let clean: Vec<f64> = t.apply(&l).iter().map(|v| 3.0 * v + 2.0).collect();
        let lost = 12 + wall.index(1, 1);
        let mut spoilt = clean.clone();
        spoilt[lost] = 1e6;
        let model = PhotoModel::with_missing(&t, DataTerm::Differences, &[lost]);
        // Its u-difference, its left neighbour's, its v-difference and the
        // one below it: four rows of D T that carried data.
        assert_eq!(model.dropped.len(), 4, "{:?}", model.dropped);
        assert_eq!(model.rows, difference_rows(&t) - 4);
        assert_eq!(model.data(&t, &spoilt), model.data(&t, &clean));
        // The spoilt value changes no background either.
        let x: Vec<f64> = l.iter().map(|v| 3.0 * v).collect();
        let b = model.backgrounds(&t, &spoilt, &x);
        assert!(b.iter().all(|b| (b - 2.0).abs() < 1e-9), "{b:?}");
        // Through the whole reconstruction: NaN marks it, and the fit is
        // the one without it.
        let mut marked = clean.clone();
        marked[lost] = f64::NAN;
        let settings = PhotoSettings {
            lambda: Some(0.0),
            iterations: 3000,
            ..Default::default()
        };
        let r = reconstruct_photo(&t, &[marked], None, &settings).unwrap();
        assert_eq!(r.unmeasured_rows, 1);
        assert!(
            r.warnings[0].contains("1 of 24 wall elements"),
            "{:?}",
            r.warnings
        );
        assert!(
            (r.channels[0].background[1] - 2.0).abs() < 0.05,
            "{:?}",
            r.channels[0]
        );
    }

    #[test]
    fn a_photo_in_other_units_gives_the_same_image_and_its_numbers_in_those_units() {
        let (wall, scene) = (Grid { nu: 10, nv: 10 }, Grid { nu: 4, nv: 4 });
        let t = bumps(wall, scene, 3.0, 0.1);
        let l: Vec<f64> = (0..16)
            .map(|k| if k % 5 == 0 { 1.0 } else { 0.2 })
            .collect();
        let i: Vec<f64> = t
            .apply(&l)
            .iter()
            .enumerate()
            .map(|(j, v)| 7.0 * v + 3.0 + 0.01 * ((j * 7919 % 13) as f64 - 6.0))
            .collect();
        let small: Vec<f64> = i.iter().map(|v| v * 2.5e-6).collect();
        let settings = PhotoSettings::default();
        let a = reconstruct_photo(&t, &[i], None, &settings).unwrap();
        let b = reconstruct_photo(&t, &[small], None, &settings).unwrap();
        let (a, b) = (&a.channels[0], &b.channels[0]);
        let diff = a
            .image
            .iter()
            .zip(&b.image)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        assert!(diff < 1e-9, "{diff:e}");
        assert!((b.gain / a.gain / 2.5e-6 - 1.0).abs() < 1e-9);
        assert!((b.lambda / a.lambda / 2.5e-6 - 1.0).abs() < 1e-9);
        assert!((b.background[0] / a.background[0] / 2.5e-6 - 1.0).abs() < 1e-9);
    }

    #[test]
    fn a_channel_noise_could_explain_is_not_stretched_to_full_scale() {
        // Red carries the scene; blue is noise about a background.
        let (wall, scene) = (Grid { nu: 12, nv: 12 }, Grid { nu: 3, nv: 3 });
        let t = bumps(wall, scene, 5.0, 0.05);
        let l = [0.2, 1.0, 0.0, 0.5, 0.7, 0.1, 0.0, 0.3, 0.9];
        let noise = |j: usize| 0.05 * (((j * 7919) % 101) as f64 / 50.0 - 1.0);
        let red: Vec<f64> = t
            .apply(&l)
            .iter()
            .enumerate()
            .map(|(j, v)| 40.0 * v + 7.0 + noise(j))
            .collect();
        let blue: Vec<f64> = (0..t.rows()).map(|j| 3.0 + noise(j + 17)).collect();
        let r = reconstruct_photo(&t, &[red, blue], None, &PhotoSettings::default()).unwrap();
        let (red, blue) = (&r.channels[0], &r.channels[1]);
        assert!(red.informative && !blue.informative, "{red:?} {blue:?}");
        assert_eq!(blue.gain, red.gain);
        let peak = |c: &PhotoChannel| c.image.iter().copied().fold(0.0, f64::max);
        assert!(
            peak(red) > 0.9 && peak(blue) < 0.1,
            "{} {}",
            peak(red),
            peak(blue)
        );
        assert!(
            r.warnings.iter().any(|w| w.starts_with("channel 1:")),
            "{:?}",
            r.warnings
        );
        assert!(r.gain_rule.contains("[1]"), "{}", r.gain_rule);
    }

    proptest::proptest! {
        /// Any shape and values: split or refused, never a panic, and what
        /// is accepted is one value per row and channel, finite or NaN (not measured).
        #[test]
        fn any_measurement_array_is_split_or_refused(
            shape in proptest::collection::vec(0usize..40, 0..4),
            rows in 0usize..40,
            data in proptest::collection::vec(proptest::prelude::any::<f64>(), 0..200),
        ) {
            if let Ok(ch) = split_channels(&shape, &data, rows) {
                proptest::prop_assert!((1..=4).contains(&ch.len()));
                proptest::prop_assert!(ch.iter().all(|c| c.len() == rows && c.iter().all(|v| !v.is_infinite())));
                proptest::prop_assert_eq!(ch.len() * rows, data.len());
            }
        }
    }
}
