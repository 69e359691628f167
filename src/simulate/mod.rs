//! Simulated measurements `i = T l` with a physical camera noise model.
//!
//! Exposure is set by the unpolarized image: `photons` photo-electrons reach
//! the brightest wall element of the same scene seen without any polarizer.
//! The polarized blocks then collect what the polarizer lets through at that
//! same exposure, so a crossed-polarizer image is darker and noisier, as on
//! the bench. Each element then gets Poisson shot noise, Gaussian read noise,
//! and quantization to `bits` with the full well mapped to full scale.

pub mod camera;
pub mod patterns;

use rand::SeedableRng;

use crate::scene::Scene;
use crate::transport::{MemoryBudget, Transport, TransportError};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal, Poisson};

/// Camera and exposure parameters of a simulated capture.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct NoiseModel {
    /// Photo-electrons at the brightest element of the unpolarized wall image;
    /// also the full well (full scale of the digitizer).
    pub photons: f64,
    /// Read noise, electrons RMS.
    pub read_noise: f64,
    /// Digitizer bit depth (1-16).
    pub bits: u32,
    /// Seed of the random generator (ChaCha8: same seed, same noise, any platform).
    pub seed: u64,
}

impl Default for NoiseModel {
    fn default() -> Self {
        Self {
            photons: 10_000.0,
            read_noise: 5.0,
            bits: 12,
            seed: 1,
        }
    }
}

/// Why a simulation could not run.
#[derive(Debug, thiserror::Error)]
pub enum SimulateError {
    /// A noise parameter is out of range.
    #[error("{name} = {value}: {reason}")]
    Parameter {
        /// Flag name.
        name: &'static str,
        /// Given value.
        value: f64,
        /// Acceptable range.
        reason: &'static str,
    },
    /// The unpolarized image is black, so exposure cannot be set.
    #[error("the scene lights no wall element as the cameras see it (the unpolarized image is black); check the truth image and the geometry")]
    Black,
}

/// A simulated measurement and the numbers that explain it.
#[derive(Debug, Clone)]
pub struct Simulation {
    /// Noisy measurement in the units of `T l` (what the solvers take).
    pub measurement: Vec<f64>,
    /// Noiseless `T l`.
    pub clean: Vec<f64>,
    /// Digital numbers per element, as the camera would record them.
    pub dn: Vec<u16>,
    /// Electrons per unit of `T l`.
    pub electrons_per_unit: f64,
    /// Units of `T l` per digital number.
    pub units_per_dn: f64,
}

impl NoiseModel {
    /// Checks every parameter.
    pub fn validate(&self) -> Result<(), SimulateError> {
        if !(self.photons > 0.0 && self.photons.is_finite()) {
            return Err(SimulateError::Parameter {
                name: "photons",
                value: self.photons,
                reason: "must be a positive number of electrons",
            });
        }
        if !(self.read_noise >= 0.0 && self.read_noise.is_finite()) {
            return Err(SimulateError::Parameter {
                name: "read-noise",
                value: self.read_noise,
                reason: "must be >= 0 electrons",
            });
        }
        if !(1..=16).contains(&self.bits) {
            return Err(SimulateError::Parameter {
                name: "bits",
                value: f64::from(self.bits),
                reason: "must be from 1 to 16",
            });
        }
        Ok(())
    }

    /// Applies the model to a clean image `clean = T l`, with exposure set by
    /// `unpolarized_peak = max(T_nopol l)`.
    pub fn apply(
        &self,
        clean: Vec<f64>,
        unpolarized_peak: f64,
    ) -> Result<Simulation, SimulateError> {
        self.apply_with_offset(clean, unpolarized_peak, 0.0)
    }

    /// [`NoiseModel::apply`] by a camera that adds `offset_dn` (its dark
    /// level) before it rounds and clips, as sensors do so that read noise
    /// below zero is not cut off; `dn` keeps the offset, `measurement` does not.
    pub fn apply_with_offset(
        &self,
        clean: Vec<f64>,
        unpolarized_peak: f64,
        offset_dn: f64,
    ) -> Result<Simulation, SimulateError> {
        self.validate()?;
        if !(unpolarized_peak > 0.0 && unpolarized_peak.is_finite()) {
            return Err(SimulateError::Black);
        }
        let electrons_per_unit = self.photons / unpolarized_peak;
        let full = f64::from((1u32 << self.bits) - 1);
        let dn_per_electron = full / self.photons;
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        let read =
            Normal::new(0.0, self.read_noise.max(0.0)).map_err(|_| SimulateError::Parameter {
                name: "read-noise",
                value: self.read_noise,
                reason: "must be >= 0 electrons",
            })?;
        let mut dn = Vec::with_capacity(clean.len());
        for &c in &clean {
            let mean = (c * electrons_per_unit).max(0.0);
            let shot = if mean > 0.0 {
                Poisson::new(mean)
                    .map(|p| p.sample(&mut rng))
                    .unwrap_or(mean)
            } else {
                0.0
            };
            let e = shot + read.sample(&mut rng);
            dn.push((e * dn_per_electron + offset_dn).round().clamp(0.0, full) as u16);
        }
        let units_per_dn = 1.0 / (dn_per_electron * electrons_per_unit);
        let measurement = dn
            .iter()
            .map(|&d| (f64::from(d) - offset_dn) * units_per_dn)
            .collect();
        Ok(Simulation {
            measurement,
            clean,
            dn,
            electrons_per_unit,
            units_per_dn,
        })
    }
}

/// Brightest element of the scene's unpolarized wall image, `max(T_nopol l)`,
/// which sets the exposure. Reuses `t` when the scene has no polarizer;
/// otherwise builds the polarizer-free `T` (one block per pose) within `budget`.
pub fn unpolarized_peak(
    scene: &Scene,
    t: &Transport,
    l: &[f64],
    budget: MemoryBudget,
) -> Result<f64, TransportError> {
    brightest_unpolarized(scene, t, &[l], budget)
}

/// [`unpolarized_peak`] over several radiances `ls` of one scene (the
/// brightest of all), building the polarizer-free `T` once.
/// Why: a moving demo object's every position must stay below full scale.
pub(crate) fn brightest_unpolarized(
    scene: &Scene,
    t: &Transport,
    ls: &[&[f64]],
    budget: MemoryBudget,
) -> Result<f64, TransportError> {
    let has_polarizer = scene.poses().iter().any(|p| !p.analyzers.is_empty());
    let open;
    let t = if has_polarizer {
        open = crate::transport::build(&scene.without_polarizers(), budget)?;
        &open
    } else {
        t
    };
    Ok(ls.iter().flat_map(|l| t.apply(l)).fold(0.0, f64::max))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_seed_same_noise_and_unbiased() {
        let m = NoiseModel {
            photons: 1e4,
            read_noise: 3.0,
            bits: 16,
            seed: 7,
        };
        let clean = vec![0.5; 4000];
        let a = m.apply(clean.clone(), 1.0).unwrap();
        let b = m.apply(clean.clone(), 1.0).unwrap();
        assert_eq!(a.measurement, b.measurement);
        let mean = a.measurement.iter().sum::<f64>() / 4000.0;
        // 5000 electrons: shot noise sigma ~71 e-, i.e. 0.0071 units; the mean of 4000 is within 4e-4.
        assert!((mean - 0.5).abs() < 4e-4, "{mean}");
        let var = a
            .measurement
            .iter()
            .map(|v| (v - mean).powi(2))
            .sum::<f64>()
            / 4000.0;
        let expect = (5000.0 + 9.0) / 1e8;
        assert!(
            (var / expect - 1.0).abs() < 0.1,
            "variance {var} vs {expect}"
        );
    }

    #[test]
    fn a_dark_level_keeps_read_noise_below_zero_from_being_clipped() {
        let m = NoiseModel {
            photons: 4095.0,
            read_noise: 3.0,
            bits: 12,
            seed: 9,
        };
        // No light: 3 e- (3 DN) of read noise around a 64 DN dark level.
        let s = m.apply_with_offset(vec![0.0; 20_000], 1.0, 64.0).unwrap();
        let mean_dn = s.dn.iter().map(|&d| f64::from(d)).sum::<f64>() / 20_000.0;
        assert!((mean_dn - 64.0).abs() < 0.1, "{mean_dn}");
        let mean = s.measurement.iter().sum::<f64>() / 20_000.0;
        assert!(mean.abs() < 0.1 * s.units_per_dn, "{mean}");
        // Without the level the same noise is clipped at 0 and biased upward.
        let clipped = m.apply(vec![0.0; 20_000], 1.0).unwrap();
        let bias = clipped.dn.iter().map(|&d| f64::from(d)).sum::<f64>() / 20_000.0;
        assert!(bias > 1.0, "{bias}");
    }

    #[test]
    fn quantization_and_saturation() {
        let m = NoiseModel {
            photons: 1e9,
            read_noise: 0.0,
            bits: 2,
            seed: 1,
        };
        let s = m.apply(vec![0.0, 0.34, 1.0, 3.0], 1.0).unwrap();
        assert_eq!(s.dn, vec![0, 1, 3, 3]);
    }

    #[test]
    fn bad_parameters_are_named() {
        let m = NoiseModel {
            bits: 0,
            ..NoiseModel::default()
        };
        assert!(m
            .apply(vec![1.0], 1.0)
            .unwrap_err()
            .to_string()
            .starts_with("bits = 0"));
        let m = NoiseModel {
            photons: f64::NAN,
            ..NoiseModel::default()
        };
        assert!(m.validate().is_err());
        assert!(matches!(
            NoiseModel::default().apply(vec![0.0], 0.0),
            Err(SimulateError::Black)
        ));
    }
}
