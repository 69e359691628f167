//! The HTTP API: axum routes over the daemon's typed state, nothing else.
//!
//! Errors are JSON `{ "error": code, "detail": text }` with the right status;
//! jobs answer 202 with a `Location`. Mutating requests need the bearer token
//! when one is set. Request bodies are size-limited.

mod error;
mod openapi;
mod routes;

use std::sync::Arc;

use axum::extract::{Request, State};
use axum::http::Method;
use axum::middleware::{self, Next};
use axum::response::Response;
use axum::routing::{get, post, put};
use axum::Router;

pub use error::ApiError;

use crate::daemon::Daemon;

/// The router for a running daemon.
pub fn router(d: Arc<Daemon>) -> Router {
    let limit = d.config.queue.max_body_bytes;
    Router::new()
        .route("/health", get(routes::health))
        .route("/metrics", get(routes::metrics))
        .route("/camera", get(routes::camera))
        .route("/camera/settings", put(routes::camera_settings))
        .route(
            "/captures",
            post(routes::post_capture).get(routes::list_captures),
        )
        .route("/captures/{id}", get(routes::get_capture))
        .route("/captures/{id}/frame.tiff", get(routes::capture_frames))
        .route("/captures/{id}/mean.tiff", get(routes::capture_mean))
        .route("/captures/{id}/preview.png", get(routes::capture_preview))
        .route(
            "/reconstructions",
            post(routes::post_reconstruction).get(routes::list_reconstructions),
        )
        .route("/reconstructions/{id}", get(routes::get_reconstruction))
        .route(
            "/reconstructions/{id}/image.png",
            get(routes::reconstruction_image),
        )
        .route(
            "/reconstructions/{id}/recovered.npy",
            get(routes::reconstruction_npy),
        )
        .route("/jobs/{id}", get(routes::get_job))
        .route("/events", get(routes::events))
        .route("/scenes", get(routes::scenes))
        .route("/scenes/{name}/exposure", get(routes::scene_exposure))
        .route("/openapi.json", get(openapi::spec))
        .fallback(routes::not_found)
        .layer(middleware::from_fn_with_state(d.clone(), auth))
        .layer(axum::extract::DefaultBodyLimit::max(limit))
        .with_state(d)
}

/// Requires `Authorization: Bearer <token>` on mutating requests when a token is set.
async fn auth(
    State(d): State<Arc<Daemon>>,
    req: Request,
    next: Next,
) -> Result<Response, ApiError> {
    let mutating = !matches!(*req.method(), Method::GET | Method::HEAD | Method::OPTIONS);
    if mutating && !d.token.is_empty() {
        let given = req
            .headers()
            .get(axum::http::header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.strip_prefix("Bearer "));
        if !given.is_some_and(|t| constant_time_eq(t.as_bytes(), d.token.as_bytes())) {
            return Err(ApiError::unauthorized());
        }
    }
    Ok(next.run(req).await)
}

fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}
