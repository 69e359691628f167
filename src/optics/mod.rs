//! Pure optics of the wall: Fresnel reflectance, the GGX microfacet model, the
//! diffuse term and the camera polarizer's action on the reflected ray (MODEL.md "One entry of T").
//!
//! Everything here is a pure function of unit vectors and material constants,
//! so it can be unit-tested against limits and symmetries and reused by the
//! transport builder, the simulator and the benchmarks alike.

pub(crate) mod brdf;
pub(crate) mod diffuse;
pub(crate) mod fresnel;
pub(crate) mod ggx;
pub mod polarizer;

/// Three-vector used across the crate (metres or unit directions).
pub type Vec3 = nalgebra::Vector3<f64>;

pub(crate) use brdf::Brdf;
pub use brdf::Polarization;
pub use diffuse::DiffuseModel;
pub use polarizer::PolarizerModel;
