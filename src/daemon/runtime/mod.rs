//! The daemon's runtime: its configuration, the job queues and registry,
//! the event stream, the metrics, retention, the scenes it knows, the camera
//! service and the fake camera's demo. Each is a small handle that owns its
//! state; the jobs and procedures get the handles they need, never the daemon.

pub(crate) mod camera;
pub mod config;
pub(crate) mod demo;
pub(crate) mod events;
pub(crate) mod live;
pub(crate) mod metrics;
pub(crate) mod queue;
pub(crate) mod registry;
pub(crate) mod retention;
pub mod scene_registry;
pub mod scenes;
pub(crate) mod wall_views;
