//! Calibrating a real bench from images instead of hand-typed numbers:
//! [`geometry`] fits each pose's camera→wall homography to an image of a
//! dot target on the wall (pure functions over frames; no I/O).

pub mod geometry;
