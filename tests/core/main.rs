//! The numeric core and the offline tools, one test binary: the transport
//! matrix against its literal model and Python, revision 3's measurement,
//! stability where the methods fail, λ from one measurement, the layers'
//! boundaries, the CLI, and the cases Mitsuba 3 rendered. One binary, not
//! one per file: each binary links the whole graph, and libtest runs one
//! binary's tests side by side (docs/test-times.md).

pub(crate) mod cli;
mod colour;
mod lambda;
mod layers;
mod occluder;
mod photo;
#[cfg(feature = "report")]
mod rendered;
mod rev3;
pub(crate) mod scene_fit;
mod shadows;
mod stability;
mod transport;
