//! Handlers: parse, ask the daemon, answer. No business logic lives here.
//! One file per resource; this one has what they share and the daemon-wide
//! routes (health, metrics, events, the fallbacks).

use std::convert::Infallible;
use std::sync::Arc;

use axum::body::Body;
use axum::extract::State;
use axum::http::{header, StatusCode};
use axum::response::sse::{Event as SseEvent, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::Json;
use futures_util::Stream;
use tokio_stream::wrappers::BroadcastStream;
use tokio_stream::StreamExt;

use super::bodies::{
    Accepted, CaptureAccepted, CaptureBody, ErrorBody, Health, ImportQuery, Page, PlanBody,
    SettingsBody, TargetQuery,
};
use super::extract::{ApiJson, ApiPath as Path, ApiQuery as Query};
use super::ApiError;
use crate::daemon::runtime::metrics::{counter, gauge, Metrics};
use crate::daemon::{Daemon, JobKind};
use crate::measure::exposure::BlockExposure;
use crate::store::{CaptureFiles, CaptureRecord, JobState, Listing, ReconstructionRecord};

type St = State<Arc<Daemon>>;

mod calibrations;
mod camera;
mod captures;
mod jobs;
mod live;
mod plans;
mod reconstructions;
mod rig;
mod scenes;

pub use calibrations::*;
pub use camera::*;
pub use captures::*;
pub use jobs::*;
pub use live::*;
pub use plans::*;
pub use reconstructions::*;
pub use rig::*;
pub use scenes::*;

/// Header of a list answer naming the rows of the page that the catalogue
/// could not read (comma-separated ids); absent when every row was read.
pub const UNREADABLE_HEADER: &str = "polnlos-unreadable";

/// A page of a list as a JSON array; rows that could not be read are named
/// in [`UNREADABLE_HEADER`], so the array keeps its shape for every client.
fn listing<T: serde::Serialize>(l: Listing<T>) -> Response {
    let mut r = Json(l.records).into_response();
    if !l.unreadable.is_empty() {
        let ids: Vec<String> = l.unreadable.iter().map(i64::to_string).collect();
        if let Ok(v) = header::HeaderValue::from_str(&ids.join(",")) {
            r.headers_mut().insert(UNREADABLE_HEADER, v);
        }
    }
    r
}

/// A path's id: a positive whole number, else 400 (a request that cannot be
/// read, not a thing that does not exist).
fn parse_id(raw: &str, kind: &str) -> Result<i64, ApiError> {
    raw.parse::<i64>().ok().filter(|v| *v > 0).ok_or_else(|| {
        ApiError::new(
            StatusCode::BAD_REQUEST,
            "bad_id",
            format!("{raw:?} is not a {kind} id (a positive whole number)"),
        )
    })
}

/// Liveness and camera connection.
#[utoipa::path(get, path = "/health", responses((status = 200, body = Health, description = "The daemon is up")))]
pub async fn health(State(d): St) -> Json<Health> {
    Json(Health {
        status: "ok",
        camera_connected: d.camera().status().connected,
        version: env!("CARGO_PKG_VERSION"),
    })
}

/// Prometheus metrics.
#[utoipa::path(get, path = "/metrics", responses((status = 200, description = "Prometheus text format", content_type = "text/plain")))]
pub async fn metrics(State(d): St) -> Response {
    let mut samples = d.metric_samples();
    samples.extend([
        gauge(
            "polnlos_http_connections_open",
            "HTTP connections open",
            Metrics::get(&super::serve::CONNECTIONS_OPEN),
        ),
        counter(
            "polnlos_http_connections_refused_total",
            "HTTP connections closed at once because max_connections were open",
            Metrics::get(&super::serve::CONNECTIONS_REFUSED),
        ),
    ]);
    (
        [(header::CONTENT_TYPE, "text/plain; version=0.0.4")],
        Metrics::render(&samples),
    )
        .into_response()
}

/// 202 with the job's `Location`.
fn accepted(kind: &str, id: i64, body: impl serde::Serialize) -> Response {
    let location = format!("/{kind}s/{id}");
    (
        StatusCode::ACCEPTED,
        [(header::LOCATION, location)],
        Json(body),
    )
        .into_response()
}

async fn file(
    path: std::path::PathBuf,
    content_type: &'static str,
    what: String,
) -> Result<Response, ApiError> {
    match tokio::fs::read(&path).await {
        Ok(bytes) => {
            Ok(([(header::CONTENT_TYPE, content_type)], Body::from(bytes)).into_response())
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Err(ApiError::not_found(format!(
            "{what} has no such file yet (is it done?)"
        ))),
        Err(e) => Err(ApiError::internal(format!(
            "{what}: cannot read its file ({e})"
        ))),
    }
}

/// Server-sent events: job progress, frames taken, camera state changes.
#[utoipa::path(get, path = "/events", responses((status = 200, content_type = "text/event-stream", description = "Event stream")))]
pub async fn events(State(d): St) -> Sse<impl Stream<Item = Result<SseEvent, Infallible>>> {
    let stream = BroadcastStream::new(d.subscribe()).filter_map(|e| {
        let e = e.ok()?;
        SseEvent::default().json_data(&e).ok().map(Ok)
    });
    // The stream ends when the server stops, so a listener does not hold the shutdown.
    let stream = futures_util::StreamExt::take_until(stream, d.streams_closed());
    Sse::new(stream).keep_alive(KeepAlive::default())
}

/// Unknown path.
pub async fn not_found(uri: axum::http::Uri) -> ApiError {
    let path: String = uri.path().chars().take(200).collect();
    ApiError::not_found(format!("no route {path}; see /openapi.json"))
}

/// A known path with a method it does not have.
pub async fn method_not_allowed(method: axum::http::Method, uri: axum::http::Uri) -> ApiError {
    let path: String = uri.path().chars().take(200).collect();
    ApiError::new(
        axum::http::StatusCode::METHOD_NOT_ALLOWED,
        "method_not_allowed",
        format!("{path} does not take {method}; see /openapi.json"),
    )
}
