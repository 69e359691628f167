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
use tokio_stream::wrappers::BroadcastStream;
use tokio_stream::StreamExt;

use super::bodies::{
    Accepted, CaptureAccepted, CaptureBody, ErrorBody, Health, Page, PlanBody, ReconstructionBody,
    SettingsBody, TargetQuery,
};
use super::extract::{ApiJson, ApiPath as Path, ApiQuery as Query};
use super::ApiError;
use crate::daemon::metrics::{counter, gauge, Metrics};
use crate::daemon::{Daemon, JobKind};
use crate::measure::exposure::BlockExposure;
use crate::store::{CaptureFiles, CaptureRecord, JobState, Listing, ReconstructionRecord};

type St = State<Arc<Daemon>>;

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

/// Camera identity, ranges, counters, connection state, and its settings as
/// read back from it now (during a capture: as that capture set them, with
/// `busy` naming the capture).
#[utoipa::path(get, path = "/camera", responses((status = 200, body = crate::daemon::CameraView, description = "Camera state")))]
pub async fn camera(State(d): St) -> Json<crate::daemon::CameraView> {
    Json(d.camera().now().await)
}

/// The rotation mount that turns the polarizer: its kind and port, the angle
/// read from it now (as last read while a capture turns it), and its last error.
#[utoipa::path(get, path = "/mount", responses((status = 200, body = crate::daemon::rig::mount::MountView, description = "Mount state")))]
pub async fn mount(State(d): St) -> Json<crate::daemon::rig::mount::MountView> {
    Json(d.mount_now().await)
}

/// The relay that switches the hidden scene's light for dark frames: its
/// kind, port and relay, whether the light was on when last read, and its last error.
#[utoipa::path(get, path = "/light", responses((status = 200, body = crate::daemon::rig::light::LightView, description = "Light switch state")))]
pub async fn light(State(d): St) -> Json<crate::daemon::rig::light::LightView> {
    Json(d.light_now())
}

/// The camera stage that moves the camera between poses: its kind, the pose
/// it last reached, the position read back, and its last error.
#[utoipa::path(get, path = "/stage", responses((status = 200, body = crate::daemon::rig::stage::StageView, description = "Stage state")))]
pub async fn stage(State(d): St) -> Json<crate::daemon::rig::stage::StageView> {
    Json(d.stage_now())
}

/// Finds the mount angle at which the polarizer is crossed: sweeps the
/// mount around its zero with the camera at `pose`, fits the minimum of the
/// polarizer's intensity law to the wall's mean light, and makes it the
/// zero (kept in the data directory). Holds the camera like a capture.
#[utoipa::path(post, path = "/mount/zero", request_body = crate::daemon::ZeroBody, responses((status = 200, body = crate::daemon::ZeroFit, description = "The zero found, now in force, and the sweep"), (status = 404, description = "Unknown scene"), (status = 422, description = "No mount, a value out of range, or no minimum in the sweep"), (status = 503, description = "No camera, or the mount did not turn")))]
pub async fn mount_zero(
    State(d): St,
    ApiJson(b): ApiJson<crate::daemon::ZeroBody>,
) -> Result<Json<crate::daemon::ZeroFit>, ApiError> {
    Ok(Json(d.calibrate_mount_zero(b).await?))
}

/// `?live=true&stretch=true` of `GET /camera/frame.png`.
#[derive(Debug, Default, serde::Deserialize, utoipa::IntoParams)]
#[serde(deny_unknown_fields)]
pub struct FrameQuery {
    /// Take a fresh frame when no capture has the camera (the live view);
    /// while a capture runs, its latest frame either way.
    #[serde(default)]
    live: bool,
    /// Auto-contrast: the 0.5th..99.5th percentile to black..white (a
    /// crossed-polarizer frame peaks at a few percent of full scale).
    #[serde(default)]
    stretch: bool,
    /// On a polarizer-mosaic camera: `raw` (the mosaic as read out), `s0`
    /// (intensity), `dolp` (degree of linear polarization) or `aolp` (its
    /// angle), the last three at half resolution.
    #[serde(default)]
    #[param(value_type = Option<String>)]
    view: crate::measure::mosaic::View,
}

/// The latest frame (with `live=true`, a fresh one when the camera is idle),
/// as a 16-bit PNG scaled to full scale or stretched; its levels (histogram,
/// peak, saturated share, stretch) in the `polnlos-levels` header as JSON.
#[utoipa::path(get, path = "/camera/frame.png", params(FrameQuery), responses((status = 200, content_type = "image/png", description = "The frame; header polnlos-levels: its levels as JSON", headers(("polnlos-levels" = String, description = "JSON: full_scale, histogram (64 bins from histogram_low to histogram_high DN), histogram_low, histogram_high, peak, saturated, low, high (the stretch)"))), (status = 404, body = ErrorBody, description = "No frame yet (no camera, or none delivered)")))]
pub async fn camera_frame(State(d): St, Query(q): Query<FrameQuery>) -> Result<Response, ApiError> {
    let frame = if q.live {
        d.camera().live_frame().await
    } else {
        d.camera().latest_frame()
    };
    let frame = frame.ok_or_else(|| {
        ApiError::not_found("no frame yet: the camera has delivered none (is it connected?)")
    })?;
    if q.view == crate::measure::mosaic::View::Colour {
        return colour_frame(&d, frame, q.stretch).await;
    }
    // The Stokes views read the mosaic the camera's settings say the frame holds.
    let mosaic = match q.view {
        crate::measure::mosaic::View::Raw => None,
        view => {
            let settings = d.camera().status().info.map(|i| i.settings);
            let layout = settings.and_then(|s| s.pixel_format.mosaic()).ok_or_else(|| {
                ApiError::invalid(format!(
                    "view={view:?} is for a polarizer-mosaic camera; this camera reads out {} (use view=raw, or a polarization pixel_format)",
                    settings.map_or("no frames yet".to_string(), |s| s.pixel_format.name().to_string())
                ))
            })?;
            let region = settings.map_or([0, 0, 0, 0], |s| s.region);
            Some((layout, [region[0], region[1]], view))
        }
    };
    let (png, levels) = tokio::task::spawn_blocking(move || {
        let (width, height, pixels, bits) = match mosaic {
            Some((layout, offset, view)) => crate::measure::mosaic::view(
                &frame.pixels,
                (frame.width, frame.height, frame.bits),
                layout,
                offset,
                view,
            ),
            None => (frame.width, frame.height, frame.pixels.to_vec(), frame.bits),
        };
        let levels = crate::measure::levels::levels(&pixels, bits)
            .ok_or_else(|| "the frame has no pixels".to_string())?;
        let shown = crate::measure::levels::display_u16(&pixels, &levels, q.stretch);
        let png = crate::files::image::encode_png16(width, height, &shown)?;
        Ok::<_, String>((png, levels))
    })
    .await
    .map_err(|e| ApiError::internal(e.to_string()))?
    .map_err(ApiError::internal)?;
    live_png(png, &levels)
}

/// `GET /camera/frame.png?view=colour`: a colour camera's raw `frame` in
/// colour, one RGB pixel per 2x2 cell, every channel on one stretch; 422
/// for a camera without a Bayer filter.
async fn colour_frame(
    d: &Daemon,
    frame: Arc<crate::camera::RawFrame>,
    stretch: bool,
) -> Result<Response, ApiError> {
    let settings = d.camera().status().info.map(|i| i.settings);
    let pattern = settings.and_then(|s| s.pixel_format.bayer()).ok_or_else(|| {
        ApiError::invalid(format!(
            "view=colour is for a colour camera reading out its raw Bayer frames; this camera reads out {} (use view=raw, or a Bayer pixel_format)",
            settings.map_or("no frames yet".to_string(), |s| s.pixel_format.name().to_string())
        ))
    })?;
    let region = settings.map_or([0, 0, 0, 0], |s| s.region);
    let (png, levels) = tokio::task::spawn_blocking(move || {
        let (w, h, rgb) = crate::measure::colour::cells_rgb(
            &frame.pixels,
            (frame.width, frame.height),
            pattern,
            [region[0], region[1]],
        );
        let levels = crate::measure::levels::levels(&rgb, frame.bits)
            .ok_or_else(|| "the frame has no whole 2x2 cell".to_string())?;
        let shown = crate::measure::levels::display_u16(&rgb, &levels, stretch);
        let png = crate::files::image::encode_png_rgb16(w, h, &shown)?;
        Ok::<_, String>((png, levels))
    })
    .await
    .map_err(|e| ApiError::internal(e.to_string()))?
    .map_err(ApiError::internal)?;
    live_png(png, &levels)
}

/// A live-view PNG with its `levels` in the `polnlos-levels` header, never cached.
fn live_png(png: Vec<u8>, levels: &crate::measure::levels::Levels) -> Result<Response, ApiError> {
    let levels = serde_json::to_string(levels).map_err(|e| ApiError::internal(e.to_string()))?;
    Ok((
        [
            (header::CONTENT_TYPE, "image/png".to_string()),
            (header::CACHE_CONTROL, "no-store".to_string()),
            (header::HeaderName::from_static("polnlos-levels"), levels),
        ],
        png,
    )
        .into_response())
}

/// Changes the capture defaults (any subset of the settings; the rest keep
/// theirs) and applies them to the camera now (queued captures keep their
/// own). 409 while a capture has the camera.
#[utoipa::path(put, path = "/camera/settings", request_body = SettingsBody, responses((status = 200, body = crate::camera::CameraInfo, description = "Applied; the camera's description with its settings read back"), (status = 409, description = "A capture is running"), (status = 422, description = "Out of range"), (status = 503, description = "No camera")))]
pub async fn camera_settings(
    State(d): St,
    ApiJson(s): ApiJson<SettingsBody>,
) -> Result<Json<crate::camera::CameraInfo>, ApiError> {
    Ok(Json(d.camera().put_settings(s.change).await?))
}

/// Queues a capture.
#[utoipa::path(post, path = "/captures", request_body = CaptureBody, responses((status = 202, body = CaptureAccepted, description = "Queued; Location names the capture; the body echoes every setting it will use"), (status = 404, description = "Unknown scene"), (status = 422, description = "Out of range"), (status = 429, description = "Queue full"), (status = 507, description = "Its files would not fit on the disk")))]
pub async fn post_capture(
    State(d): St,
    ApiJson(b): ApiJson<CaptureBody>,
) -> Result<Response, ApiError> {
    let (id, req) = d.submit_capture(b).await?;
    Ok(accepted("capture", id, CaptureAccepted::new(id, &req)))
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

/// Queues an acquisition plan: every block of the scene, then its
/// reconstruction; operator steps wait for `POST /plans/{id}/continue`.
#[utoipa::path(post, path = "/plans", request_body = PlanBody, responses((status = 202, body = crate::daemon::PlanView, description = "Queued; Location names the plan; the body lists its steps"), (status = 404, description = "Unknown scene"), (status = 422, description = "A capture of the plan would be refused")))]
pub async fn post_plan(State(d): St, ApiJson(b): ApiJson<PlanBody>) -> Result<Response, ApiError> {
    let view = d.submit_plan(b).await?;
    Ok(accepted("plan", view.plan.id, view))
}

/// Plans, newest first.
#[utoipa::path(get, path = "/plans", params(Page), responses((status = 200, body = [crate::store::PlanRow], headers(("polnlos-unreadable" = String, description = "Ids of this page's rows the catalogue could not read")))))]
pub async fn list_plans(State(d): St, Query(p): Query<Page>) -> Result<Response, ApiError> {
    let (limit, offset) = p.get()?;
    Ok(listing(d.store().plans(limit, offset)?))
}

/// One plan: its state, the step it is at, the operator's prompt, its
/// captures, its reconstruction and every step.
#[utoipa::path(get, path = "/plans/{id}", params(("id" = String, Path, description = "The plan's id, a positive whole number")), responses((status = 200, body = crate::daemon::PlanView), (status = 404, description = "No such plan")))]
pub async fn get_plan(
    State(d): St,
    Path(id): Path<String>,
) -> Result<Json<crate::daemon::PlanView>, ApiError> {
    Ok(Json(d.plan_view(parse_id(&id, "plan")?)?))
}

/// Cancels a plan that has not ended (and the capture or reconstruction it
/// waits on); the captures it took are kept.
#[utoipa::path(delete, path = "/plans/{id}", params(("id" = String, Path, description = "The plan's id, a positive whole number")), responses((status = 200, body = crate::daemon::PlanView), (status = 404, description = "No such plan"), (status = 409, description = "It already ended")))]
pub async fn cancel_plan(
    State(d): St,
    Path(id): Path<String>,
) -> Result<Json<crate::daemon::PlanView>, ApiError> {
    Ok(Json(d.cancel_plan(parse_id(&id, "plan")?).await?))
}

/// The operator did what the plan's prompt asked: it goes on.
#[utoipa::path(post, path = "/plans/{id}/continue", params(("id" = String, Path, description = "The plan's id, a positive whole number")), responses((status = 200, body = crate::daemon::PlanView), (status = 404, description = "No such plan"), (status = 409, description = "It is not waiting for the operator")))]
pub async fn continue_plan(
    State(d): St,
    Path(id): Path<String>,
) -> Result<Json<crate::daemon::PlanView>, ApiError> {
    Ok(Json(d.continue_plan(parse_id(&id, "plan")?)?))
}

/// Captures, newest first.
#[utoipa::path(get, path = "/captures", params(Page), responses((status = 200, body = [CaptureRecord], headers(("polnlos-unreadable" = String, description = "Ids of this page's rows the catalogue could not read (left out of the array; the daemon's log says why)")))))]
pub async fn list_captures(State(d): St, Query(p): Query<Page>) -> Result<Response, ApiError> {
    let (limit, offset) = p.get()?;
    Ok(listing(d.store().captures(limit, offset)?))
}

/// One capture.
#[utoipa::path(get, path = "/captures/{id}", params(("id" = String, Path, description = "The capture's id, a positive whole number")), responses((status = 200, body = CaptureRecord), (status = 404, description = "No such capture")))]
pub async fn get_capture(
    State(d): St,
    Path(id): Path<String>,
) -> Result<Json<CaptureRecord>, ApiError> {
    Ok(Json(d.store().capture(parse_id(&id, "capture")?)?))
}

/// What a `DELETE` removed.
#[derive(Debug, serde::Serialize, utoipa::ToSchema)]
pub struct Deleted {
    /// The capture deleted, if a capture was asked for.
    pub capture: Option<i64>,
    /// The reconstructions deleted (with the capture, or the one asked for).
    pub reconstructions: Vec<i64>,
}

/// `?with_reconstructions=true` of `DELETE /captures/{id}`.
#[derive(Debug, serde::Deserialize, utoipa::IntoParams)]
#[serde(deny_unknown_fields)]
pub struct DeleteQuery {
    /// Also delete the (ended) reconstructions that use the capture; without
    /// it a capture a reconstruction uses is refused with 409 naming them.
    #[serde(default)]
    with_reconstructions: bool,
}

/// Deletes a capture: its catalogue row and its files, and with
/// `with_reconstructions=true` the reconstructions that use it.
#[utoipa::path(delete, path = "/captures/{id}", params(("id" = String, Path, description = "The capture's id, a positive whole number"), DeleteQuery), responses((status = 200, body = Deleted, description = "Deleted, row and files"), (status = 404, description = "No such capture"), (status = 409, description = "Queued or running, or used by a reconstruction (named)")))]
pub async fn delete_capture(
    State(d): St,
    Path(id): Path<String>,
    Query(q): Query<DeleteQuery>,
) -> Result<Json<Deleted>, ApiError> {
    let id = parse_id(&id, "capture")?;
    let reconstructions =
        tokio::task::spawn_blocking(move || d.delete_capture(id, q.with_reconstructions))
            .await
            .map_err(|e| ApiError::internal(e.to_string()))??;
    Ok(Json(Deleted {
        capture: Some(id),
        reconstructions,
    }))
}

/// Deletes an ended reconstruction: its catalogue row and its files.
#[utoipa::path(delete, path = "/reconstructions/{id}", params(("id" = String, Path, description = "The reconstruction's id, a positive whole number")), responses((status = 200, body = Deleted, description = "Deleted, row and files"), (status = 404, description = "No such reconstruction"), (status = 409, description = "Queued or running")))]
pub async fn delete_reconstruction(
    State(d): St,
    Path(id): Path<String>,
) -> Result<Json<Deleted>, ApiError> {
    let id = parse_id(&id, "reconstruction")?;
    tokio::task::spawn_blocking(move || d.delete_reconstruction(id))
        .await
        .map_err(|e| ApiError::internal(e.to_string()))??;
    Ok(Json(Deleted {
        capture: None,
        reconstructions: vec![id],
    }))
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
    d.store().capture(id)?;
    file(
        d.store().capture_dir(id).join(name),
        ct,
        format!("capture {id}"),
    )
    .await
}

/// Raw frames, multi-page 16-bit TIFF with metadata.
#[utoipa::path(get, path = "/captures/{id}/frame.tiff", params(("id" = String, Path, description = "The capture's id, a positive whole number")), responses((status = 200, content_type = "image/tiff", description = "Raw frames"), (status = 404, body = ErrorBody, description = "No such capture, or its file is not written yet")))]
pub async fn capture_frames(State(d): St, Path(id): Path<String>) -> Result<Response, ApiError> {
    capture_file(&d, &id, CaptureFiles::FRAMES, "image/tiff").await
}

/// Mean dark-subtracted frame, 32-bit float TIFF.
#[utoipa::path(get, path = "/captures/{id}/mean.tiff", params(("id" = String, Path, description = "The capture's id, a positive whole number")), responses((status = 200, content_type = "image/tiff", description = "Mean frame"), (status = 404, body = ErrorBody, description = "No such capture, or its file is not written yet")))]
pub async fn capture_mean(State(d): St, Path(id): Path<String>) -> Result<Response, ApiError> {
    capture_file(&d, &id, CaptureFiles::MEAN, "image/tiff").await
}

/// Raw dark frames taken within the capture, multi-page 16-bit TIFF.
#[utoipa::path(get, path = "/captures/{id}/dark.tiff", params(("id" = String, Path, description = "The capture's id, a positive whole number")), responses((status = 200, content_type = "image/tiff", description = "Raw dark frames"), (status = 404, body = ErrorBody, description = "No such capture, or it took no dark frames")))]
pub async fn capture_dark(State(d): St, Path(id): Path<String>) -> Result<Response, ApiError> {
    capture_file(&d, &id, CaptureFiles::DARK, "image/tiff").await
}

/// Per-pixel variance of the mean frame, 32-bit float TIFF (2 frames or more).
#[utoipa::path(get, path = "/captures/{id}/variance.tiff", params(("id" = String, Path, description = "The capture's id, a positive whole number")), responses((status = 200, content_type = "image/tiff", description = "Variance of the mean"), (status = 404, body = ErrorBody, description = "No such capture, or it has fewer than 2 frames")))]
pub async fn capture_variance(State(d): St, Path(id): Path<String>) -> Result<Response, ApiError> {
    capture_file(&d, &id, CaptureFiles::VARIANCE, "image/tiff").await
}

/// 16-bit PNG preview of the mean frame.
#[utoipa::path(get, path = "/captures/{id}/preview.png", params(("id" = String, Path, description = "The capture's id, a positive whole number")), responses((status = 200, content_type = "image/png", description = "Preview"), (status = 404, body = ErrorBody, description = "No such capture, or its file is not written yet")))]
pub async fn capture_preview(State(d): St, Path(id): Path<String>) -> Result<Response, ApiError> {
    capture_file(&d, &id, CaptureFiles::PREVIEW, "image/png").await
}

/// The latest progressive reconstruction of a capture that asked for one,
/// 16-bit PNG on the scene grid (updated while frames arrive).
#[utoipa::path(get, path = "/captures/{id}/progressive.png", params(("id" = String, Path, description = "The capture's id, a positive whole number")), responses((status = 200, content_type = "image/png", description = "Latest progressive image"), (status = 404, body = ErrorBody, description = "No such capture, or no progressive step yet")))]
pub async fn capture_progressive_image(
    State(d): St,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    capture_file(&d, &id, crate::daemon::PROGRESSIVE_IMAGE, "image/png").await
}

/// Every progressive step of a capture so far: frames, iterations, change
/// from the previous step, PSNR when a truth was given.
#[utoipa::path(get, path = "/captures/{id}/progressive.json", params(("id" = String, Path, description = "The capture's id, a positive whole number")), responses((status = 200, body = [crate::daemon::ProgressiveStep], description = "Progressive steps"), (status = 404, body = ErrorBody, description = "No such capture, or no progressive step yet")))]
pub async fn capture_progressive_steps(
    State(d): St,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    capture_file(
        &d,
        &id,
        crate::daemon::PROGRESSIVE_STEPS,
        "application/json",
    )
    .await
}

/// The radiometric gain of each scene that has one, as reconstructions
/// use it (and `polnlos measure --gain` takes it).
#[utoipa::path(get, path = "/calibrations", responses((status = 200, body = crate::daemon::Calibrations, description = "The gains in use")))]
pub async fn list_calibrations(State(d): St) -> Json<crate::daemon::Calibrations> {
    Json(d.calibrations())
}

/// Fits the pose of a target capture: its homography, reprojection error,
/// and the scene file rewritten with it.
#[utoipa::path(post, path = "/calibrations", request_body = crate::api::bodies::CalibrationBody, responses((status = 200, body = crate::daemon::GeometryCalibration, description = "The fitted pose and the scene file to review"), (status = 404, body = ErrorBody, description = "No such capture"), (status = 422, body = ErrorBody, description = "Not a done target capture, or the dots could not be found or identified")))]
pub async fn post_calibration(
    State(d): St,
    ApiJson(b): ApiJson<crate::api::bodies::CalibrationBody>,
) -> Result<Json<crate::daemon::GeometryCalibration>, ApiError> {
    let r =
        tokio::task::spawn_blocking(move || d.calibrate_geometry(b.capture, b.target.as_deref()))
            .await
            .map_err(|e| ApiError::internal(e.to_string()))??;
    Ok(Json(r))
}

/// Fits the wall (alpha, ior, kd) and the radiometric gain to point-source
/// captures, with standard errors; refused when the model cannot explain them.
#[utoipa::path(post, path = "/calibrations/wall", request_body = crate::api::bodies::WallCalibrationBody, responses((status = 200, body = crate::daemon::WallCalibration, description = "The fit"), (status = 404, body = ErrorBody, description = "No such scene or capture"), (status = 422, body = ErrorBody, description = "Not done source captures of every block, or the model leaves the measurement unexplained")))]
pub async fn post_wall_calibration(
    State(d): St,
    ApiJson(b): ApiJson<crate::api::bodies::WallCalibrationBody>,
) -> Result<Json<crate::daemon::WallCalibration>, ApiError> {
    let positions = b.positions().map_err(ApiError::invalid)?;
    let r = tokio::task::spawn_blocking(move || d.calibrate_wall(&b.scene, &positions))
        .await
        .map_err(|e| ApiError::internal(e.to_string()))??;
    Ok(Json(r))
}

/// Queues a reconstruction.
#[utoipa::path(post, path = "/reconstructions", request_body = ReconstructionBody, responses((status = 202, body = Accepted, description = "Queued; Location names the reconstruction"), (status = 404, description = "Unknown scene or capture"), (status = 422, description = "Invalid"), (status = 429, description = "Queue full")))]
pub async fn post_reconstruction(
    State(d): St,
    ApiJson(b): ApiJson<ReconstructionBody>,
) -> Result<Response, ApiError> {
    let id = d.submit_reconstruction(&b)?;
    Ok(accepted(
        "reconstruction",
        id,
        Accepted::queued("reconstruction", id),
    ))
}

/// Reconstructions, newest first.
#[utoipa::path(get, path = "/reconstructions", params(Page), responses((status = 200, body = [ReconstructionRecord], headers(("polnlos-unreadable" = String, description = "Ids of this page's rows the catalogue could not read (left out of the array; the daemon's log says why)")))))]
pub async fn list_reconstructions(
    State(d): St,
    Query(p): Query<Page>,
) -> Result<Response, ApiError> {
    let (limit, offset) = p.get()?;
    Ok(listing(d.store().reconstructions(limit, offset)?))
}

/// One reconstruction, with kappa and the report when done.
#[utoipa::path(get, path = "/reconstructions/{id}", params(("id" = String, Path, description = "The reconstruction's id, a positive whole number")), responses((status = 200, body = ReconstructionRecord), (status = 404, description = "No such reconstruction")))]
pub async fn get_reconstruction(
    State(d): St,
    Path(id): Path<String>,
) -> Result<Json<ReconstructionRecord>, ApiError> {
    Ok(Json(
        d.store().reconstruction(parse_id(&id, "reconstruction")?)?,
    ))
}

async fn recon_file(
    d: &Daemon,
    id: &str,
    name: &str,
    ct: &'static str,
) -> Result<Response, ApiError> {
    let id = parse_id(id, "reconstruction")?;
    d.store().reconstruction(id)?;
    file(
        d.store().reconstruction_dir(id).join(name),
        ct,
        format!("reconstruction {id}"),
    )
    .await
}

/// `?scale=8` of `GET /reconstructions/{id}/image.png`.
#[derive(Debug, Default, serde::Deserialize, utoipa::IntoParams)]
#[serde(deny_unknown_fields)]
pub struct ImageQuery {
    /// Enlarge each scene element to a `scale` x `scale` block of pixels
    /// (1 to 4096 / the image's longest side); absent: one pixel each.
    scale: Option<u32>,
}

/// Recovered image, 16-bit PNG, one pixel per scene element or enlarged.
#[utoipa::path(get, path = "/reconstructions/{id}/image.png", params(("id" = String, Path, description = "The reconstruction's id, a positive whole number"), ImageQuery), responses((status = 200, content_type = "image/png", description = "Recovered image"), (status = 404, body = ErrorBody, description = "No such reconstruction, or its file is not written yet"), (status = 422, body = ErrorBody, description = "A scale out of range")))]
pub async fn reconstruction_image(
    State(d): St,
    Path(id): Path<String>,
    Query(q): Query<ImageQuery>,
) -> Result<Response, ApiError> {
    let Some(k) = q.scale else {
        return recon_file(&d, &id, "image.png", "image/png").await;
    };
    let id = parse_id(&id, "reconstruction")?;
    d.store().reconstruction(id)?;
    let path = d.store().reconstruction_dir(id).join("image.png");
    let png = tokio::fs::read(&path)
        .await
        .map_err(|_| ApiError::not_found(format!("reconstruction {id} has no image.png yet")))?;
    let scaled = tokio::task::spawn_blocking(move || crate::files::image::scale_png16(&png, k))
        .await
        .map_err(|e| ApiError::internal(e.to_string()))?
        .map_err(ApiError::invalid)?;
    Ok(([(header::CONTENT_TYPE, "image/png")], scaled).into_response())
}

/// The known truth the reconstruction was asked to compare with, on its
/// scene grid, at the scale of its result (0..1 to black..white).
#[utoipa::path(get, path = "/reconstructions/{id}/truth.png", params(("id" = String, Path, description = "The reconstruction's id, a positive whole number")), responses((status = 200, content_type = "image/png", description = "The truth image"), (status = 404, body = ErrorBody, description = "No such reconstruction, or it names no truth")))]
pub async fn reconstruction_truth(
    State(d): St,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let id = parse_id(&id, "reconstruction")?;
    let png = tokio::task::spawn_blocking(move || {
        let rec = d.store().reconstruction(id)?;
        d.truth_png(&rec).map_err(ApiError::internal)
    })
    .await
    .map_err(|e| ApiError::internal(e.to_string()))??
    .ok_or_else(|| ApiError::not_found(format!("reconstruction {id} names no truth")))?;
    Ok(([(header::CONTENT_TYPE, "image/png")], png).into_response())
}

/// Recovered image, .npy (float64, scene grid).
#[utoipa::path(get, path = "/reconstructions/{id}/recovered.npy", params(("id" = String, Path, description = "The reconstruction's id, a positive whole number")), responses((status = 200, content_type = "application/octet-stream", description = "Recovered image"), (status = 404, body = ErrorBody, description = "No such reconstruction, or its file is not written yet")))]
pub async fn reconstruction_npy(
    State(d): St,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    recon_file(&d, &id, "recovered.npy", "application/octet-stream").await
}

/// The stacked measurement a reconstruction solved, .npy (float64, units of
/// `T l`, MODEL.md row order).
#[utoipa::path(get, path = "/reconstructions/{id}/measurement.npy", params(("id" = String, Path, description = "The reconstruction's id, a positive whole number")), responses((status = 200, content_type = "application/octet-stream", description = "Measurement vector"), (status = 404, body = ErrorBody, description = "No such reconstruction, or its file is not written yet")))]
pub async fn reconstruction_measurement(
    State(d): St,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    recon_file(&d, &id, "measurement.npy", "application/octet-stream").await
}

/// A reconstruction's report, as `polnlos reconstruct` writes it.
#[utoipa::path(get, path = "/reconstructions/{id}/report.json", params(("id" = String, Path, description = "The reconstruction's id, a positive whole number")), responses((status = 200, content_type = "application/json", description = "report.json"), (status = 404, body = ErrorBody, description = "No such reconstruction, or its file is not written yet")))]
pub async fn reconstruction_report(
    State(d): St,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    recon_file(&d, &id, "report.json", "application/json").await
}

/// A job id `capture-<n>` or `reconstruction-<n>`, parsed.
fn parse_job(id: &str) -> Result<(JobKind, i64), ApiError> {
    let bad = || {
        ApiError::not_found(format!(
            "{id:?} is not a job id; jobs are capture-<n> or reconstruction-<n>"
        ))
    };
    let (kind, n) = id.split_once('-').ok_or_else(bad)?;
    let n = n.parse::<i64>().ok().filter(|n| *n > 0).ok_or_else(bad)?;
    match kind {
        "capture" => Ok((JobKind::Capture, n)),
        "reconstruction" => Ok((JobKind::Reconstruction, n)),
        _ => Err(bad()),
    }
}

/// The record of a job, with its `job` id.
fn job_record(d: &Daemon, kind: JobKind, n: i64) -> Result<serde_json::Value, ApiError> {
    let v = match kind {
        JobKind::Capture => serde_json::to_value(d.store().capture(n)?),
        JobKind::Reconstruction => serde_json::to_value(d.store().reconstruction(n)?),
    };
    let mut v = v.map_err(|e| ApiError::internal(e.to_string()))?;
    v["job"] = serde_json::Value::String(format!("{}-{n}", kind.name()));
    Ok(v)
}

/// A job by id: `capture-<n>` or `reconstruction-<n>`.
#[utoipa::path(get, path = "/jobs/{id}", params(("id" = String, Path, description = "capture-<n> or reconstruction-<n>")), responses((status = 200, description = "The capture or reconstruction"), (status = 404, body = ErrorBody, description = "No such job")))]
pub async fn get_job(
    State(d): St,
    Path(id): Path<String>,
) -> Result<Json<serde_json::Value>, ApiError> {
    let (kind, n) = parse_job(&id)?;
    Ok(Json(job_record(&d, kind, n)?))
}

/// Cancels a queued or running job. A running capture stops at its next
/// frame and keeps no file of it; a running reconstruction stops between
/// its stages or within 10 solver iterations. 200 with the record once it is `cancelled`; 202 if it is
/// still stopping after 5 s.
#[utoipa::path(delete, path = "/jobs/{id}", params(("id" = String, Path, description = "capture-<n> or reconstruction-<n>")), responses((status = 200, description = "Cancelled: the job's record"), (status = 202, description = "Still stopping: the job's record"), (status = 404, body = ErrorBody, description = "No such job"), (status = 409, body = ErrorBody, description = "The job already ended")))]
pub async fn cancel_job(State(d): St, Path(id): Path<String>) -> Result<Response, ApiError> {
    let (kind, n) = parse_job(&id)?;
    let state = d.cancel_job(kind, n).await?;
    let status = if state == JobState::Running {
        StatusCode::ACCEPTED
    } else {
        StatusCode::OK
    };
    Ok((status, Json(job_record(&d, kind, n)?)).into_response())
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

/// Scene names the daemon knows.
#[utoipa::path(get, path = "/scenes", responses((status = 200, body = [String], description = "Scene names")))]
pub async fn scenes(State(d): St) -> Json<Vec<String>> {
    Json(d.scene_names())
}

/// The planned exposure and frame count of every (pose, angle) block of a scene.
#[utoipa::path(get, path = "/scenes/{name}/exposure", params(("name" = String, Path, description = "Scene name"), TargetQuery), responses((status = 200, body = [BlockExposure]), (status = 404, description = "Unknown scene"), (status = 422, description = "No calibration, or a target out of range")))]
pub async fn scene_exposure(
    State(d): St,
    Path(name): Path<String>,
    Query(q): Query<TargetQuery>,
) -> Result<Json<Vec<BlockExposure>>, ApiError> {
    let target = q.target();
    let plan = tokio::task::spawn_blocking(move || d.exposure_plan(&name, &target))
        .await
        .map_err(|e| ApiError::internal(e.to_string()))??;
    Ok(Json(plan))
}

/// Where each pose of a scene sees its wall, in sensor pixels: the live
/// view zooms onto it.
#[utoipa::path(get, path = "/scenes/{name}/wall", params(("name" = String, Path, description = "Scene name")), responses((status = 200, body = [crate::daemon::scenes::WallView]), (status = 404, body = ErrorBody, description = "Unknown scene")))]
pub async fn scene_wall(
    State(d): St,
    Path(name): Path<String>,
) -> Result<Json<Vec<crate::daemon::scenes::WallView>>, ApiError> {
    Ok(Json(d.wall_views(&name)?))
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
