//! Captures to the measurement a reconstruction solves: each (pose, angle)
//! block of `T` matched to the one capture taken there, the captures stacked
//! in block order ([`super::stack`]), and the result put in units of `T l`.
//!
//! Why one function: the daemon (from its store) and `polnlos measure` (from
//! a user's TIFF files) must give the same `i` for the same frames.

use super::colour::{BayerPattern, Colour};
use super::{stack, BlockFrames, MeasureError, Measurement, PixelMaps};
use crate::scene::{Cells, Channel, Frame, Scene};
use crate::transport::{Block, Transport};

/// One capture as the measurement needs it: where it was taken and its
/// averaged frames.
#[derive(Debug, Clone)]
pub struct CaptureFrames {
    /// How errors name it: `capture 12`, `frames-A.tiff`.
    pub name: String,
    /// Pose name in the scene.
    pub pose: String,
    /// The blocks its frames hold, in the order it yields them: one for a
    /// capture through a sheet (or none), four for a mosaic sensor's.
    pub channels: Vec<Channel>,
    /// Mean frame minus the mean dark frame, DN.
    pub mean: Frame,
    /// Variance of the mean, DN², when there were 2 frames or more.
    pub variance: Option<Frame>,
    /// Frames averaged into the mean.
    pub frames: usize,
    /// Full scale of the pixel format, DN.
    pub full_scale: f64,
    /// Exposure per frame, microseconds.
    pub exposure_us: f64,
    /// The frame's region offset on the sensor, unbinned pixels (`[0, 0]` when unknown).
    pub offset: [u32; 2],
    /// The frame's binning (`[1, 1]` when unknown).
    pub binning: [u32; 2],
    /// The sensor's Bayer filter, for a colour camera's raw frames.
    pub bayer: Option<BayerPattern>,
}

impl CaptureFrames {
    /// One simulated exposure of the whole sensor, in electrons (its mean
    /// and variance, e.g. from `simulate::camera::expose`): full scale
    /// `scale` (the electrons of the unpolarized peak) puts `i` in units of `T l`.
    ///
    /// Why: the bench's camera-frame comparisons measure their frames as a
    /// capture is measured, through [`assemble`].
    pub fn exposure(
        name: String,
        pose: String,
        channels: Vec<Channel>,
        (mean, variance): (Frame, Frame),
        scale: f64,
    ) -> Self {
        Self {
            name,
            pose,
            channels,
            mean,
            variance: Some(variance),
            frames: 1,
            full_scale: scale,
            exposure_us: 1.0,
            offset: [0, 0],
            binning: [1, 1],
            bayer: None,
        }
    }

    /// Whether it holds `block`: taken at its pose, through its analyzer.
    pub fn serves(&self, block: &Block) -> bool {
        block.taken_by(&self.pose, &self.channels)
    }
}

/// For each block of `blocks` (MODEL.md block order), the index in
/// `captures` of the one capture that serves it: a capture yielding a block
/// the scene lacks, a block without a capture, or two captures for one block
/// is an error naming them.
pub(crate) fn match_blocks(
    blocks: &[Block],
    captures: &[CaptureFrames],
) -> Result<Vec<usize>, MeasureError> {
    // Every block a capture yields must be one the scene has.
    let stray = captures.iter().find_map(|c| {
        c.channels
            .iter()
            .find(|ch| {
                !blocks
                    .iter()
                    .any(|b| b.pose == c.pose && b.channel.same(**ch))
            })
            .map(|&channel| {
                (
                    c,
                    Block {
                        pose: c.pose.clone(),
                        channel,
                    },
                )
            })
    });
    if let Some((c, block)) = stray {
        return Err(MeasureError::NoBlock {
            capture: c.name.clone(),
            block: block.label(),
            blocks: blocks
                .iter()
                .map(Block::label)
                .collect::<Vec<_>>()
                .join(", "),
        });
    }
    let mut order = Vec::with_capacity(blocks.len());
    for block in blocks {
        let mut serving = captures.iter().enumerate().filter(|(_, c)| c.serves(block));
        let (first, _) = serving.next().ok_or_else(|| MeasureError::NoCapture {
            block: block.label(),
        })?;
        if let Some((second, _)) = serving.next() {
            return Err(MeasureError::TwoCaptures {
                block: block.label(),
                first: captures[first].name.clone(),
                second: captures[second].name.clone(),
            });
        }
        order.push(first);
    }
    Ok(order)
}

/// The measurement of `captures` for `scene`: each block's capture averaged
/// over every wall element's pixels through its pose's homography and
/// stacked in the order of `blocks`, in fractions of full scale per
/// microsecond (MODEL.md "From camera frames to i").
pub fn assemble(
    scene: &Scene,
    blocks: &[Block],
    captures: &[CaptureFrames],
) -> Result<Measurement, MeasureError> {
    assemble_with(scene, blocks, captures, &PixelMaps::default())
}

/// [`assemble`] with the pixel maps kept in `maps` (made on first use), for
/// a caller that measures the same poses again (a progressive reconstruction).
pub fn assemble_with(
    scene: &Scene,
    blocks: &[Block],
    captures: &[CaptureFrames],
    maps: &PixelMaps,
) -> Result<Measurement, MeasureError> {
    assemble_colour(scene, blocks, captures, maps, None)
}

/// `assemble_with` for one `colour` of each capture's Bayer filter
/// (`None`: every pixel as it is): each element's pixels take that colour's
/// value interpolated from its own pixels ([`crate::scene::PixelMap::interpolated`]),
/// one channel of a colour measurement. A capture without a Bayer filter
/// cannot give a colour.
pub fn assemble_colour(
    scene: &Scene,
    blocks: &[Block],
    captures: &[CaptureFrames],
    maps: &PixelMaps,
    colour: Option<Colour>,
) -> Result<Measurement, MeasureError> {
    let order = match_blocks(blocks, captures)?;
    let mut homographies = Vec::with_capacity(order.len());
    for (block, &k) in blocks.iter().zip(&order) {
        let c = &captures[k];
        let pose = scene
            .pose(&c.pose)
            .ok_or_else(|| MeasureError::UnknownPose {
                capture: c.name.clone(),
                pose: c.pose.clone(),
            })?;
        let h = pose.homography.ok_or_else(|| MeasureError::NoHomography {
            pose: pose.name.clone(),
        })?;
        // A mosaic block is measured over its micro-polarizer's pixels only.
        let cell = pose.analyzer(block.channel).and_then(|a| a.cell);
        if cell.is_some() && c.binning != [1, 1] {
            return Err(MeasureError::Capture {
                capture: c.name.clone(),
                reason: format!(
                    "it was binned {:?}, but pose {:?} has a polarizer mosaic: a binned pixel mixes its micro-polarizers; capture with binning [1, 1]",
                    c.binning, pose.name
                ),
            });
        }
        let colour_cells = match (colour, c.bayer) {
            (None, _) => None,
            (Some(colour), Some(bayer)) => Some(bayer.cells(colour)),
            (Some(colour), None) => {
                return Err(MeasureError::Capture {
                    capture: c.name.clone(),
                    reason: format!(
                        "it has no Bayer filter, so it has no {colour:?} channel; measure a colour camera's raw frames, or all channels of this one together"
                    ),
                })
            }
        };
        if colour.is_some() && c.binning != [1, 1] {
            return Err(MeasureError::Capture {
                capture: c.name.clone(),
                reason: format!(
                    "it was binned {:?}, but its sensor has a Bayer filter: a binned pixel mixes its colours; capture with binning [1, 1]",
                    c.binning
                ),
            });
        }
        homographies.push((h, Cells::from(cell), colour_cells));
    }
    let frames: Vec<BlockFrames<'_>> = order
        .iter()
        .zip(&homographies)
        .map(|(&k, (h, cells, colour))| {
            let c = &captures[k];
            BlockFrames {
                pose: &c.pose,
                homography: h,
                cells: *cells,
                colour: *colour,
                mean: &c.mean,
                variance: c.variance.as_ref(),
                frames: c.frames,
                full_scale: c.full_scale,
                exposure_us: c.exposure_us,
                offset: c.offset,
                binning: c.binning,
            }
        })
        .collect();
    stack(&frames, &scene.wall().plane, maps)
}

/// How a measurement was put in units of `T l`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Units {
    /// Divided by a radiometric calibration (`[calibration]` in the config,
    /// `calibrate wall`'s gain): absolute.
    Calibrated(f64),
    /// No calibration: divided by the factor that makes the brightest
    /// element of a Tikhonov solution about 1 (the box constraint needs a
    /// scale). Relative only.
    Estimated(f64),
}

impl Units {
    /// The factor the measurement was divided by.
    pub fn factor(self) -> f64 {
        match self {
            Units::Calibrated(c) | Units::Estimated(c) => c,
        }
    }

    /// What a user should be told about it, if anything: a note (a fact
    /// about the bench, not a fault of this result).
    pub fn note(self) -> Option<String> {
        match self {
            Units::Calibrated(_) => None,
            Units::Estimated(_) => Some("no radiometric calibration for this scene: the measurement was scaled so that the brightest element is about 1".to_string()),
        }
    }
}

impl Units {
    /// The scale [`Units::Estimated`] describes, for `m` under `t`.
    pub fn estimate(t: &Transport, m: &Measurement) -> Result<Units, crate::solve::SolveError> {
        let probe = crate::solve::Solver::TIKHONOV.run(&crate::solve::Problem::new(
            t,
            &m.i,
            crate::solve::SolveRequest {
                solver: crate::solve::Solver::TIKHONOV,
                ..Default::default()
            },
        ))?;
        let unclipped_max = probe.image.iter().copied().fold(0.0, f64::max).max(1e-300);
        let fit = t.apply(&probe.image);
        let fit_dot_i = fit.iter().zip(&m.i).map(|(a, b)| a * b).sum::<f64>();
        let fit_dot_fit = fit.iter().map(|a| a * a).sum::<f64>();
        let lsq_scale = fit_dot_i.max(1e-300) / fit_dot_fit.max(1e-300);
        Ok(Units::Estimated(lsq_scale * unclipped_max))
    }

    /// Divides `m` by the factor, its variance by the factor's square.
    pub fn apply(self, m: &mut Measurement) {
        let s = self.factor();
        m.i.iter_mut().for_each(|v| *v /= s);
        m.variance.iter_mut().flatten().for_each(|v| *v /= s * s);
    }
}

/// Puts `m` in units of `T l`: divided by `calibration` when there is one
/// (and it is positive), else by the scale [`Units::Estimated`] describes.
pub fn to_model_units(
    t: &Transport,
    m: &mut Measurement,
    calibration: Option<f64>,
) -> Result<Units, crate::solve::SolveError> {
    let units = match calibration.filter(|c| *c > 0.0 && c.is_finite()) {
        Some(c) => Units::Calibrated(c),
        None => Units::estimate(t, m)?,
    };
    units.apply(m);
    Ok(units)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::MemoryBudget;

    fn scene() -> Scene {
        match Scene::builtin("brewster-multi-3x3") {
            Some(Ok(s)) => s,
            _ => panic!("built-in scene"),
        }
    }

    fn capture(name: &str, pose: &str, channel: Channel, value: f32) -> CaptureFrames {
        CaptureFrames {
            name: name.into(),
            pose: pose.into(),
            channels: vec![channel],
            mean: Frame {
                width: 512,
                height: 512,
                pixels: vec![value; 512 * 512],
            },
            variance: None,
            frames: 1,
            full_scale: 1000.0,
            exposure_us: 10.0,
            offset: [0, 0],
            binning: [1, 1],
            bayer: None,
        }
    }

    #[test]
    fn captures_given_in_any_order_stack_in_block_order() {
        let s = scene();
        let blocks = crate::transport::blocks_of(&s);
        assert!(blocks.len() >= 2, "{blocks:?}");
        // One capture per block, given in reverse, each with its own level.
        let captures: Vec<_> = blocks
            .iter()
            .enumerate()
            .rev()
            .map(|(k, b)| capture(&format!("c{k}"), &b.pose, b.channel, 100.0 * (k + 1) as f32))
            .collect();
        let m = assemble(&s, &blocks, &captures).expect("every block has its capture");
        let n = s.wall().plane.grid.count();
        for (k, _) in blocks.iter().enumerate() {
            let want = 100.0 * (k + 1) as f64 / 1000.0 / 10.0;
            assert!(
                (m.i[k * n] - want).abs() < 1e-9,
                "block {k}: {} != {want}",
                m.i[k * n]
            );
        }
    }

    #[test]
    fn a_missing_a_doubled_or_a_stray_capture_is_named() {
        let s = scene();
        let blocks = crate::transport::blocks_of(&s);
        let b0 = &blocks[0];
        let e = assemble(&s, &blocks, &[capture("c0", &b0.pose, b0.channel, 1.0)]).unwrap_err();
        assert!(
            matches!(e, MeasureError::NoCapture { ref block } if *block == blocks[1].label()),
            "{e}"
        );
        let mut all: Vec<_> = blocks
            .iter()
            .map(|b| capture("c", &b.pose, b.channel, 1.0))
            .collect();
        all.push(capture("again", &b0.pose, b0.channel, 1.0));
        let e = assemble(&s, &blocks, &all).unwrap_err().to_string();
        assert!(e.contains(&b0.label()) && e.contains("again"), "{e}");
        all.pop();
        all.push(capture("stray", "B", Channel::Sheet { deg: 33.0 }, 1.0));
        let e = assemble(&s, &blocks, &all).unwrap_err().to_string();
        assert!(e.contains("stray was taken at B-pol33"), "{e}");
    }

    #[test]
    fn each_colour_of_a_bayer_capture_averages_its_own_pixels() {
        let s = scene();
        let blocks = crate::transport::blocks_of(&s);
        // A raw frame whose red pixels read 100, green 200, blue 300.
        let captures: Vec<_> = blocks
            .iter()
            .map(|b| {
                let mut c = capture("raw", &b.pose, b.channel, 0.0);
                c.bayer = Some(BayerPattern::GR);
                for y in 0..512 {
                    for x in 0..512 {
                        c.mean.pixels[y * 512 + x] =
                            match BayerPattern::GR.colour_at(x as i64, y as i64) {
                                Colour::Red => 100.0,
                                Colour::Green => 200.0,
                                Colour::Blue => 300.0,
                            };
                    }
                }
                c
            })
            .collect();
        let maps = PixelMaps::default();
        for (colour, want) in Colour::ALL.into_iter().zip([100.0, 200.0, 300.0]) {
            let m = assemble_colour(&s, &blocks, &captures, &maps, Some(colour)).unwrap();
            let want = want / 1000.0 / 10.0;
            assert!(
                m.i.iter().all(|v| (v - want).abs() < 1e-12),
                "{colour:?}: {:?}",
                &m.i[..3]
            );
        }
        // All pixels together: a footprint-weighted mix, between red and blue.
        let all = assemble_with(&s, &blocks, &captures, &maps).unwrap();
        assert!(
            all.i.iter().all(|v| *v > 0.0105 && *v < 0.0295),
            "{:?}",
            &all.i[..3]
        );
        // A monochrome capture has no colour; a binned Bayer frame mixes them.
        let mut mono = captures.clone();
        mono[0].bayer = None;
        let e = assemble_colour(&s, &blocks, &mono, &maps, Some(Colour::Red)).unwrap_err();
        assert!(e.to_string().contains("no Bayer filter"), "{e}");
        let mut binned = captures;
        binned[0].binning = [2, 2];
        let e = assemble_colour(&s, &blocks, &binned, &maps, Some(Colour::Blue)).unwrap_err();
        assert!(e.to_string().contains("binning [1, 1]"), "{e}");
    }

    #[test]
    fn a_calibration_divides_and_its_absence_scales_to_about_one() {
        let s = crate::scene::Scene::builtin("brewster-crossed")
            .and_then(Result::ok)
            .expect("built-in scene");
        let t = crate::transport::build(&s, MemoryBudget::DEFAULT).expect("T");
        let truth = vec![0.5; t.cols()];
        let i = t.apply(&truth);
        let mut m = Measurement {
            i: i.iter().map(|v| v * 40.0).collect(),
            variance: Some(vec![4.0; i.len()]),
        };
        assert_eq!(
            to_model_units(&t, &mut m.clone(), Some(40.0)).unwrap(),
            Units::Calibrated(40.0)
        );
        let mut c = m.clone();
        to_model_units(&t, &mut c, Some(40.0)).unwrap();
        assert!(
            (c.i[3] - i[3]).abs() < 1e-12 && (c.variance.unwrap()[0] - 4.0 / 1600.0).abs() < 1e-15
        );
        let units = to_model_units(&t, &mut m, None).unwrap();
        assert!(units.note().is_some());
        // A flat 0.5 scene scaled so its brightest element is about 1.
        let ratio = m.i[3] / i[3];
        assert!((ratio - 2.0).abs() < 0.1, "{ratio}");
    }
}
