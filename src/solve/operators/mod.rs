//! The linear operators the solvers share: the Gram `T^T T` (dense or low
//! rank), triangular solves, and the TV gradient and its adjoint.

pub mod gram;
pub(crate) mod lowrank;
pub(crate) mod triangular;
pub(crate) mod tv;
