//! The HTTP API: axum routes over the daemon's typed state, nothing else.
//!
//! Errors are JSON `{ "error": code, "detail": text }` with the right status,
//! whatever went wrong (a bad query string, a wrong method, an oversized
//! header); jobs answer 202 with a `Location`. Every request passes
//! [`guard`]: size limits, the `Host`/`Origin` checks, and the bearer token
//! when one is set. Request bodies are size- and time-limited; [`serve`] caps
//! connections and header time; [`run`] serves a daemon until shut down.

pub mod bodies;
mod error;
mod extract;
mod guard;
mod openapi;
mod routes;
pub mod serve;
mod web;

use std::sync::Arc;
use std::time::Duration;

use axum::middleware;
use axum::routing::{get, post, put};
use axum::Router;

pub use error::ApiError;
pub use serve::{run, serve, Limits};

use crate::daemon::Daemon;

/// The router for a running daemon.
pub fn router(d: Arc<Daemon>) -> Router {
    let limit = d.config().queue.max_body_bytes;
    let body_timeout = Duration::from_secs_f64(d.config().http.body_timeout_s);
    Router::new()
        .route("/", get(web::index))
        .route("/app.js", get(web::app))
        .route("/style.css", get(web::style))
        .route("/api", get(web::api))
        .route("/api.js", get(web::api_js))
        .route("/bench/{name}", get(web::chart))
        .route("/camera/frame.png", get(routes::camera_frame))
        .route("/health", get(routes::health))
        .route("/metrics", get(routes::metrics))
        .route("/camera", get(routes::camera))
        .route("/camera/settings", put(routes::camera_settings))
        .route(
            "/captures",
            post(routes::post_capture).get(routes::list_captures),
        )
        .route(
            "/captures/{id}",
            get(routes::get_capture).delete(routes::delete_capture),
        )
        .route("/captures/{id}/frame.tiff", get(routes::capture_frames))
        .route("/captures/{id}/mean.tiff", get(routes::capture_mean))
        .route("/captures/{id}/dark.tiff", get(routes::capture_dark))
        .route(
            "/captures/{id}/variance.tiff",
            get(routes::capture_variance),
        )
        .route("/captures/{id}/preview.png", get(routes::capture_preview))
        .route(
            "/captures/{id}/progressive.png",
            get(routes::capture_progressive_image),
        )
        .route(
            "/captures/{id}/progressive.json",
            get(routes::capture_progressive_steps),
        )
        .route("/calibrations", post(routes::post_calibration))
        .route("/calibrations/wall", post(routes::post_wall_calibration))
        .route(
            "/reconstructions",
            post(routes::post_reconstruction).get(routes::list_reconstructions),
        )
        .route(
            "/reconstructions/{id}",
            get(routes::get_reconstruction).delete(routes::delete_reconstruction),
        )
        .route(
            "/reconstructions/{id}/image.png",
            get(routes::reconstruction_image),
        )
        .route(
            "/reconstructions/{id}/truth.png",
            get(routes::reconstruction_truth),
        )
        .route(
            "/reconstructions/{id}/recovered.npy",
            get(routes::reconstruction_npy),
        )
        .route(
            "/reconstructions/{id}/measurement.npy",
            get(routes::reconstruction_measurement),
        )
        .route(
            "/reconstructions/{id}/report.json",
            get(routes::reconstruction_report),
        )
        .route(
            "/jobs/{id}",
            get(routes::get_job).delete(routes::cancel_job),
        )
        .route("/events", get(routes::events))
        .route("/scenes", get(routes::scenes))
        .route("/scenes/{name}/exposure", get(routes::scene_exposure))
        .route("/openapi.json", get(openapi::spec))
        .fallback(routes::not_found)
        .method_not_allowed_fallback(routes::method_not_allowed)
        .layer(tower_http::timeout::RequestBodyTimeoutLayer::new(
            body_timeout,
        ))
        .layer(axum::extract::DefaultBodyLimit::max(limit))
        .layer(middleware::from_fn_with_state(
            guard::Guard::new(d.clone()),
            guard::guard,
        ))
        .with_state(d)
}
