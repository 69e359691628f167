//! Handlers: parse, ask the daemon, answer. No business logic lives here.

use std::convert::Infallible;
use std::sync::Arc;

use axum::body::Body;
use axum::extract::State;
use axum::http::{header, StatusCode};
use axum::response::sse::{Event as SseEvent, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::Json;
use futures_util::Stream;
use serde::Deserialize;
use tokio_stream::wrappers::BroadcastStream;
use tokio_stream::StreamExt;

use super::extract::{ApiJson, ApiPath as Path, ApiQuery as Query};
use super::ApiError;
use crate::camera::CameraSettings;
use crate::daemon::metrics::{Metrics, Sample};
use crate::daemon::{
    camera_limits, exposure_plan, validate_capture, validate_reconstruction, CaptureBody, Daemon,
    ReconstructionBody,
};
use crate::measure::exposure::{BlockExposure, ExposureTarget};
use crate::store::{CaptureFiles, CaptureRecord, ReconstructionRecord};

type St = State<Arc<Daemon>>;

/// Paging of list endpoints.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[serde(deny_unknown_fields)]
pub struct Page {
    /// At most this many (1-1000, default 100).
    limit: Option<u64>,
    /// Skip this many (0 to 2^63 - 1).
    offset: Option<u64>,
}

impl Page {
    fn get(&self) -> Result<(usize, usize), ApiError> {
        let limit = self.limit.unwrap_or(100);
        if !(1..=1000).contains(&limit) {
            return Err(ApiError::invalid(format!(
                "limit = {limit}: must be from 1 to 1000"
            )));
        }
        let offset = self.offset.unwrap_or(0);
        // SQLite's OFFSET is a signed 64-bit integer: beyond it, refuse rather than wrap.
        let offset = i64::try_from(offset)
            .ok()
            .and_then(|o| usize::try_from(o).ok())
            .ok_or_else(|| {
                ApiError::invalid(format!("offset = {offset}: must be from 0 to {}", i64::MAX))
            })?;
        Ok((limit as usize, offset))
    }
}

fn parse_id(raw: &str, kind: &str) -> Result<i64, ApiError> {
    raw.parse::<i64>().ok().filter(|v| *v > 0).ok_or_else(|| {
        ApiError::not_found(format!(
            "{raw:?} is not a {kind} id (a positive whole number)"
        ))
    })
}

/// Liveness and camera connection.
#[utoipa::path(get, path = "/health", responses((status = 200, description = "The daemon is up")))]
pub async fn health(State(d): St) -> Json<serde_json::Value> {
    let s = d.camera.status();
    Json(
        serde_json::json!({ "status": "ok", "camera_connected": s.connected, "version": env!("CARGO_PKG_VERSION") }),
    )
}

/// Prometheus metrics.
#[utoipa::path(get, path = "/metrics", responses((status = 200, description = "Prometheus text format", content_type = "text/plain")))]
pub async fn metrics(State(d): St) -> Response {
    let mut samples = d.metric_samples();
    samples.extend([
        Sample {
            name: "polnlos_http_connections_open",
            kind: "gauge",
            help: "HTTP connections open",
            value: Metrics::get(&super::serve::CONNECTIONS_OPEN),
        },
        Sample {
            name: "polnlos_http_connections_refused_total",
            kind: "counter",
            help: "HTTP connections closed at once because max_connections were open",
            value: Metrics::get(&super::serve::CONNECTIONS_REFUSED),
        },
    ]);
    (
        [(header::CONTENT_TYPE, "text/plain; version=0.0.4")],
        Metrics::render(&samples),
    )
        .into_response()
}

/// Camera identity, ranges, counters, connection state, and its settings as
/// read back from it now (during a capture: as that capture set them, with
/// `busy` naming the capture).
#[utoipa::path(get, path = "/camera", responses((status = 200, description = "Camera state")))]
pub async fn camera(State(d): St) -> Json<serde_json::Value> {
    let (status, busy) = d.camera_now().await;
    let mut v = serde_json::to_value(status).unwrap_or_default();
    v["busy"] = busy.map_or(serde_json::Value::Null, serde_json::Value::String);
    v["capture_defaults"] =
        serde_json::to_value(d.capture_defaults(d.camera.status().info.as_ref()))
            .unwrap_or_default();
    Json(v)
}

/// Applies camera settings now and makes them the defaults of later captures
/// (queued captures keep their own). 409 while a capture has the camera.
#[utoipa::path(put, path = "/camera/settings", request_body = CameraSettings, responses((status = 200, description = "Applied; the camera's description with its settings read back"), (status = 409, description = "A capture is running"), (status = 422, description = "Out of range"), (status = 503, description = "No camera")))]
pub async fn camera_settings(
    State(d): St,
    ApiJson(s): ApiJson<CameraSettings>,
) -> Result<Json<crate::camera::CameraInfo>, ApiError> {
    Ok(Json(d.put_camera_settings(s).await?))
}

fn accepted(kind: &str, id: i64, extra: serde_json::Value) -> Response {
    let location = format!("/{kind}s/{id}");
    let mut body =
        serde_json::json!({ "id": id, "state": "queued", "job": format!("{kind}-{id}") });
    if let (Some(b), serde_json::Value::Object(e)) = (body.as_object_mut(), extra) {
        b.extend(e);
    }
    (
        StatusCode::ACCEPTED,
        [(header::LOCATION, location)],
        Json(body),
    )
        .into_response()
}

/// Queues a capture.
#[utoipa::path(post, path = "/captures", request_body = CaptureBody, responses((status = 202, description = "Queued; Location names the capture; the body echoes every setting it will use"), (status = 404, description = "Unknown scene"), (status = 422, description = "Out of range"), (status = 429, description = "Queue full"), (status = 507, description = "Its files would not fit on the disk")))]
pub async fn post_capture(
    State(d): St,
    ApiJson(b): ApiJson<CaptureBody>,
) -> Result<Response, ApiError> {
    // Validation may build the scene's T (for "exposure": "auto"): off the runtime.
    let d2 = d.clone();
    let req = tokio::task::spawn_blocking(move || validate_capture(&d2, &b))
        .await
        .map_err(|e| ApiError::internal(e.to_string()))??;
    let id = d.submit_capture(&req)?;
    Ok(accepted(
        "capture",
        id,
        serde_json::json!({
            "kind": req.kind, "exposure_us": req.exposure_us, "gain": req.gain, "frames": req.frames,
            "dark_frames": req.dark_frames, "dark_capture": req.dark_capture,
            "pixel_format": req.pixel_format, "region": req.region, "binning": req.binning, "trigger": req.trigger,
        }),
    ))
}

/// Captures, newest first.
#[utoipa::path(get, path = "/captures", params(Page), responses((status = 200, body = [CaptureRecord])))]
pub async fn list_captures(
    State(d): St,
    Query(p): Query<Page>,
) -> Result<Json<Vec<CaptureRecord>>, ApiError> {
    let (limit, offset) = p.get()?;
    Ok(Json(d.store.captures(limit, offset)?))
}

/// One capture.
#[utoipa::path(get, path = "/captures/{id}", responses((status = 200, body = CaptureRecord), (status = 404, description = "No such capture")))]
pub async fn get_capture(
    State(d): St,
    Path(id): Path<String>,
) -> Result<Json<CaptureRecord>, ApiError> {
    Ok(Json(d.store.capture(parse_id(&id, "capture")?)?))
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

async fn capture_file(
    d: &Daemon,
    id: &str,
    name: &str,
    ct: &'static str,
) -> Result<Response, ApiError> {
    let id = parse_id(id, "capture")?;
    d.store.capture(id)?;
    file(
        d.store.capture_dir(id).join(name),
        ct,
        format!("capture {id}"),
    )
    .await
}

/// Raw frames, multi-page 16-bit TIFF with metadata.
#[utoipa::path(get, path = "/captures/{id}/frame.tiff", responses((status = 200, content_type = "image/tiff", description = "Raw frames")))]
pub async fn capture_frames(State(d): St, Path(id): Path<String>) -> Result<Response, ApiError> {
    capture_file(&d, &id, CaptureFiles::FRAMES, "image/tiff").await
}

/// Mean dark-subtracted frame, 32-bit float TIFF.
#[utoipa::path(get, path = "/captures/{id}/mean.tiff", responses((status = 200, content_type = "image/tiff", description = "Mean frame")))]
pub async fn capture_mean(State(d): St, Path(id): Path<String>) -> Result<Response, ApiError> {
    capture_file(&d, &id, CaptureFiles::MEAN, "image/tiff").await
}

/// 16-bit PNG preview of the mean frame.
#[utoipa::path(get, path = "/captures/{id}/preview.png", responses((status = 200, content_type = "image/png", description = "Preview")))]
pub async fn capture_preview(State(d): St, Path(id): Path<String>) -> Result<Response, ApiError> {
    capture_file(&d, &id, CaptureFiles::PREVIEW, "image/png").await
}

/// Queues a reconstruction.
#[utoipa::path(post, path = "/reconstructions", request_body = ReconstructionBody, responses((status = 202, description = "Queued"), (status = 404, description = "Unknown scene or capture"), (status = 422, description = "Invalid"), (status = 429, description = "Queue full")))]
pub async fn post_reconstruction(
    State(d): St,
    ApiJson(b): ApiJson<ReconstructionBody>,
) -> Result<Response, ApiError> {
    let req = validate_reconstruction(&d, &b)?;
    let permit = d.reconstructions.try_reserve().map_err(|_| {
        d.metrics
            .rejected_full
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        ApiError::queue_full("reconstruction", 5)
    })?;
    let id = d.store.insert_reconstruction(&req)?;
    permit.send(id);
    Ok(accepted("reconstruction", id, serde_json::Value::Null))
}

/// Reconstructions, newest first.
#[utoipa::path(get, path = "/reconstructions", params(Page), responses((status = 200, body = [ReconstructionRecord])))]
pub async fn list_reconstructions(
    State(d): St,
    Query(p): Query<Page>,
) -> Result<Json<Vec<ReconstructionRecord>>, ApiError> {
    let (limit, offset) = p.get()?;
    Ok(Json(d.store.reconstructions(limit, offset)?))
}

/// One reconstruction, with kappa and the report when done.
#[utoipa::path(get, path = "/reconstructions/{id}", responses((status = 200, body = ReconstructionRecord), (status = 404, description = "No such reconstruction")))]
pub async fn get_reconstruction(
    State(d): St,
    Path(id): Path<String>,
) -> Result<Json<ReconstructionRecord>, ApiError> {
    Ok(Json(
        d.store.reconstruction(parse_id(&id, "reconstruction")?)?,
    ))
}

async fn recon_file(
    d: &Daemon,
    id: &str,
    name: &str,
    ct: &'static str,
) -> Result<Response, ApiError> {
    let id = parse_id(id, "reconstruction")?;
    d.store.reconstruction(id)?;
    file(
        d.store.reconstruction_dir(id).join(name),
        ct,
        format!("reconstruction {id}"),
    )
    .await
}

/// Recovered image, 16-bit PNG.
#[utoipa::path(get, path = "/reconstructions/{id}/image.png", responses((status = 200, content_type = "image/png", description = "Recovered image")))]
pub async fn reconstruction_image(
    State(d): St,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    recon_file(&d, &id, "image.png", "image/png").await
}

/// Recovered image, .npy (float64, scene grid).
#[utoipa::path(get, path = "/reconstructions/{id}/recovered.npy", responses((status = 200, content_type = "application/octet-stream", description = "Recovered image")))]
pub async fn reconstruction_npy(
    State(d): St,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    recon_file(&d, &id, "recovered.npy", "application/octet-stream").await
}

/// A job by id: `capture-<n>` or `reconstruction-<n>`.
#[utoipa::path(get, path = "/jobs/{id}", responses((status = 200, description = "The capture or reconstruction"), (status = 404, description = "No such job")))]
pub async fn get_job(
    State(d): St,
    Path(id): Path<String>,
) -> Result<Json<serde_json::Value>, ApiError> {
    let bad = || {
        ApiError::not_found(format!(
            "{id:?} is not a job id; jobs are capture-<n> or reconstruction-<n>"
        ))
    };
    let (kind, n) = id.split_once('-').ok_or_else(bad)?;
    let n = n.parse::<i64>().ok().filter(|n| *n > 0).ok_or_else(bad)?;
    let v = match kind {
        "capture" => serde_json::to_value(d.store.capture(n)?),
        "reconstruction" => serde_json::to_value(d.store.reconstruction(n)?),
        _ => return Err(bad()),
    };
    let mut v = v.map_err(|e| ApiError::internal(e.to_string()))?;
    v["job"] = serde_json::Value::String(id.clone());
    Ok(Json(v))
}

/// Server-sent events: job progress, frames taken, camera state changes.
#[utoipa::path(get, path = "/events", responses((status = 200, content_type = "text/event-stream", description = "Event stream")))]
pub async fn events(State(d): St) -> Sse<impl Stream<Item = Result<SseEvent, Infallible>>> {
    let stream = BroadcastStream::new(d.events.subscribe()).filter_map(|e| {
        let e = e.ok()?;
        SseEvent::default().json_data(&e).ok().map(Ok)
    });
    Sse::new(stream).keep_alive(KeepAlive::default())
}

/// Scene names the daemon knows.
#[utoipa::path(get, path = "/scenes", responses((status = 200, description = "Scene names")))]
pub async fn scenes(State(d): St) -> Json<Vec<String>> {
    Json(d.scenes.names())
}

/// Target of an exposure plan (query of `GET /scenes/{name}/exposure`).
#[derive(Debug, Deserialize, utoipa::IntoParams)]
pub struct TargetQuery {
    /// Brightest admissible wall element as a fraction of full scale (default 0.8).
    peak_fraction: Option<f64>,
    /// SNR wanted there after averaging (default 100).
    snr: Option<f64>,
}

/// The planned exposure and frame count of every (pose, angle) block of a scene.
#[utoipa::path(get, path = "/scenes/{name}/exposure", params(("name" = String, Path, description = "Scene name"), TargetQuery), responses((status = 200, body = [BlockExposure]), (status = 404, description = "Unknown scene"), (status = 422, description = "No calibration, or a target out of range")))]
pub async fn scene_exposure(
    State(d): St,
    Path(name): Path<String>,
    Query(q): Query<TargetQuery>,
) -> Result<Json<Vec<BlockExposure>>, ApiError> {
    let mut target = ExposureTarget::default();
    if let Some(f) = q.peak_fraction {
        target.peak_fraction = f;
    }
    if let Some(s) = q.snr {
        target.snr = s;
    }
    let d2 = d.clone();
    let plan = tokio::task::spawn_blocking(move || {
        let limits = camera_limits(&d2, d2.camera.status().info.as_ref());
        exposure_plan(&d2, &name, &target, &limits)
    })
    .await
    .map_err(|e| ApiError::internal(e.to_string()))??;
    Ok(Json(plan))
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
