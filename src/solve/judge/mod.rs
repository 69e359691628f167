//! Judging a reconstruction: the model check against the noise, the
//! conditioning of `T`, image metrics against a truth, and the report.

pub(crate) mod adequacy;
pub(crate) mod conditioning;
pub mod metrics;
pub mod report;
