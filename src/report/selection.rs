//! What a bench run measures (sizes, sweeps, seeds) and the list of reports
//! it runs: the one file that names every report. A new report is a file
//! beside this one implementing [`Report`] and one entry in
//! [`BenchSelection::run`].

use super::shape::Report;
use super::speed;
use super::BenchError;
use crate::transport::MemoryBudget;

/// What a bench run measures: sizes, sweeps and seeds.
#[derive(Debug, Clone, serde::Serialize)]
pub struct BenchSelection {
    /// Whether this is the quick selection.
    pub quick: bool,
    /// Scene grids of the conditioning table (the last one also for the roughness sweep).
    pub grids: Vec<usize>,
    /// Voxel grids of the active-NLOS resolution sweep.
    pub active_grids: Vec<usize>,
    /// Voxel grid of the active-NLOS roughness sweep.
    pub active_roughness_grid: usize,
    /// Speed sizes (names from `speed::SIZES`).
    pub speed_sizes: Vec<&'static str>,
    /// Noise seeds per speed size.
    pub speed_seeds: u64,
    /// Iteration budgets of the iterative solvers.
    pub speed_budgets: Vec<usize>,
    /// Scene grid of the sampling sweep.
    pub sampling_grid: usize,
    /// Samples per element side of the sampling sweep's reference `T`.
    pub sampling_reference_m: usize,
    /// Wall and scene grid sides of the NumPy peer comparison.
    pub peer: (usize, usize),
    /// Built-in scenes of the automatic-λ sweep ...
    pub lambda_scenes: Vec<&'static str>,
    /// ... their hidden-scene grid side ...
    pub lambda_grid: usize,
    /// ... and photo-electron levels (3 patterns at each).
    pub lambda_photons: Vec<f64>,
    /// Folder of the Mitsuba-rendered cases ...
    pub rendered: std::path::PathBuf,
    /// ... and the cases of it reconstructed.
    pub rendered_cases: Vec<&'static str>,
    /// Wall grid side and scene grid sides of the end-to-end scaling sweep.
    pub scaling: (usize, Vec<usize>),
    /// Whether to compare a polarization camera with polarizer sheets
    /// (`super::mosaic`, about 30 s) and the revision-2 measurement with
    /// revision 3's against exposure (`super::photons`, about 90 s).
    pub mosaic: bool,
}

impl BenchSelection {
    /// About 2 s on 2 cores: 3x3 grids, the S speed size, one seed.
    pub fn quick() -> Self {
        Self {
            quick: true,
            grids: vec![3],
            active_grids: vec![2, 3],
            active_roughness_grid: 3,
            speed_sizes: vec![speed::SIZES[0].label],
            speed_seeds: 1,
            speed_budgets: vec![10, 50, 200],
            sampling_grid: 3,
            sampling_reference_m: 12,
            peer: (32, 8),
            lambda_scenes: vec!["brewster-crossed"],
            lambda_grid: 3,
            lambda_photons: vec![1e4],
            rendered: super::rendered::DEFAULT_DIR.into(),
            rendered_cases: vec!["nopol", "crossed"],
            scaling: (32, vec![8]),
            mosaic: false,
        }
    }

    /// The full run (about 5 min on 2 cores, most of it the λ sweep): adds
    /// the 8x8 grids, the M and L speed sizes with 3 seeds, finer sweeps, the
    /// λ sweep on 4 scenes at 16x16, the peer at wall 64 x scene 32, and
    /// the end-to-end reconstruction at wall 64 x scene 16 to 64 (about 2 min).
    pub fn full() -> Self {
        Self {
            quick: false,
            grids: vec![3, 8],
            active_grids: vec![2, 3, 4, 6, 8],
            active_roughness_grid: 6,
            speed_sizes: speed::SIZES.iter().map(|s| s.label).collect(),
            speed_seeds: 3,
            speed_budgets: speed::BUDGETS.to_vec(),
            sampling_grid: 8,
            sampling_reference_m: 24,
            peer: (64, 32),
            lambda_scenes: vec![
                "brewster-nopol",
                "brewster-crossed",
                "occluder-crossed",
                "brewster-multi",
            ],
            lambda_grid: 16,
            lambda_photons: vec![1e3, 1e4, 1e5],
            rendered: super::rendered::DEFAULT_DIR.into(),
            rendered_cases: super::rendered::REPORT_CASES.iter().map(|c| c.0).collect(),
            scaling: (64, vec![16, 32, 48, 64]),
            mosaic: true,
        }
    }

    /// The speed sizes of this selection.
    fn sizes(&self) -> Vec<speed::Size> {
        speed::SIZES
            .iter()
            .filter(|s| self.speed_sizes.contains(&s.label))
            .cloned()
            .collect()
    }

    /// Steps [`BenchSelection::run`] reports to its progress callback.
    pub fn steps(&self) -> usize {
        super::conditioning_len(&self.grids)
            + super::roughness_len()
            + super::stability::CASES
            + self.speed_sizes.len() * self.speed_seeds as usize
            + 2
            + super::active::active_len(&self.active_grids)
            + 1
            + super::lambda::lambda_len(self.lambda_scenes.len(), self.lambda_photons.len())
            + self.rendered_cases.len()
            + self.scaling.1.len()
            + if self.mosaic {
                super::mosaic::STEPS + super::photons::STEPS
            } else {
                0
            }
    }

    /// Runs every report, calling `step()` as each row is done, each `T`
    /// built within `budget`; the NumPy peer works in `work` (created and removed here).
    pub fn run(
        &self,
        budget: MemoryBudget,
        work: &std::path::Path,
        step: &mut dyn FnMut(),
    ) -> Result<Vec<Box<dyn Report>>, BenchError> {
        let roughness_grid = *self.grids.last().unwrap_or(&3);
        let sizes = self.sizes();
        let runs = speed::speed_sweep(&sizes, self.speed_seeds, &self.speed_budgets, budget, step)?;
        let mut reports: Vec<Box<dyn Report>> = vec![
            Box::new(super::Conditioning(super::conditioning_table(
                &self.grids,
                budget,
                step,
            )?)),
            Box::new(super::Roughness(super::roughness_sweep(
                roughness_grid,
                budget,
                step,
            )?)),
            Box::new(super::stability::Stability(
                super::stability::stability_table(budget, step)?,
            )),
            Box::new(super::sampling::Sampling {
                reference_m: self.sampling_reference_m,
                rows: super::sampling::sampling_sweep(
                    self.sampling_grid,
                    self.sampling_reference_m,
                    budget,
                    step,
                )?,
            }),
            Box::new(super::active::Active(super::active::active_sweep(
                &self.active_grids,
                self.active_roughness_grid,
                budget,
                step,
            )?)),
            Box::new({
                let peer =
                    super::peer::compare("brewster-multi", self.peer.0, self.peer.1, work, budget);
                let _ = std::fs::remove_dir_all(work);
                step();
                peer?
            }),
            Box::new(super::lambda::Lambda(super::lambda::lambda_sweep(
                &self.lambda_scenes,
                self.lambda_grid,
                &self.lambda_photons,
                budget,
                step,
            )?)),
            Box::new(super::rendered::rendered_report(
                &self.rendered,
                &self.rendered_cases,
                budget,
                step,
            )?),
            Box::new({
                let exe = std::env::current_exe()
                    .map_err(|e| BenchError::Peer(format!("the polnlos binary: {e}")))?;
                let scaling = super::scaling::scaling_sweep(
                    &exe,
                    self.scaling.0,
                    &self.scaling.1,
                    &work.join("scaling"),
                    budget,
                    step,
                );
                let _ = std::fs::remove_dir_all(work);
                scaling?
            }),
            Box::new(speed::Speed {
                seeds: self.speed_seeds,
                summary: speed::summarize(&runs),
                runs,
            }),
        ];
        if self.mosaic {
            reports.push(Box::new(super::mosaic::mosaic_report(
                &self.rendered.join("rotating/frames"),
                budget,
                step,
            )?));
            reports.push(Box::new(super::photons::photons_report(
                "brewster-crossed",
                budget,
                step,
            )?));
        }
        Ok(reports)
    }
}
