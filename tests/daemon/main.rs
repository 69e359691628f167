//! The daemon and what it drives, one test binary: the camera path through
//! Aravis's fake camera, the daemon over real HTTP on 127.0.0.1 (its
//! service, hostile clients, faults, plans, the mount, mosaics), in process
//! on the synthetic camera, the store through its database file, the
//! devices on pseudo-terminals, the parsers' fuzz targets, schemathesis, the
//! web page in Chromium and the Python package. Tests that use Aravis hold
//! `common::lock`; the others run beside them.

mod common;

mod api_fuzz;
mod camera;
mod colour;
mod faults;
mod fuzz;
mod hostile;
mod in_process;
mod live;
mod mosaic;
mod mount;
mod mount_device;
mod photos;
mod plans;
pub(crate) mod python;
mod relay_device;
mod roundtrip;
mod scene_fit;
mod scenes;
mod service;
mod verdict;
mod web;
