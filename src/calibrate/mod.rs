//! Calibrating a real bench from images instead of hand-typed numbers:
//! [`colour`] measures a colour camera's balance from a white or grey field;
//! [`geometry`] fits each pose's camera→wall homography to an image of a
//! dot target on the wall; [`occluder`] fits the occluders' position to a
//! photo; [`scene`] fits the bench's geometry (occluders, hidden plane,
//! distance) to its photos; [`wall`] fits the wall's roughness, refractive
//! index, diffuse weight and the radiometric gain to point-source captures
//! (pure functions; no I/O). The wall's and the homographies' fits share
//! one Levenberg-Marquardt (`levenberg`).

pub mod colour;
pub mod geometry;
mod levenberg;
pub mod occluder;
pub mod scene;
pub(crate) mod scene_text;
pub mod wall;
