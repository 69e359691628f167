//! polnlos: polarization-enhanced passive non-line-of-sight imaging.
//!
//! A camera looks at a rough wall through a linear polarizer set near the
//! Brewster angle; a hidden scene lights the wall. The wall image is linear in
//! the hidden radiance, `i = T l` (MODEL.md Eq. 2); polnlos builds `T` from a
//! scene file and recovers `l` with ADMM-TV (Eq. 12).
//!
//! Rooms: [`optics`] (pure physics), [`scene`] (files and geometry),
//! [`transport`] (building `T`), [`solve`] (reconstruction, conditioning,
//! metrics), [`simulate`] (noise model), [`measure`] (frames to `i`),
//! [`camera`] (frames), [`files`] (npy, png, json).

pub mod api;
pub mod bench;
pub mod camera;
pub mod daemon;
pub mod files;
pub mod measure;
pub mod optics;
pub mod scene;
pub mod simulate;
pub mod solve;
pub mod store;
pub mod transport;
