//! Calibrating a real bench from images instead of hand-typed numbers:
//! [`geometry`] fits each pose's camera→wall homography to an image of a
//! dot target on the wall; [`wall`] fits the wall's roughness, refractive
//! index, diffuse weight and the radiometric gain to point-source captures
//! (pure functions; no I/O).

pub mod geometry;
pub mod wall;
