//! `GET /openapi.json`, generated from the handlers' annotations (utoipa).

use axum::Json;
use utoipa::OpenApi;

use super::routes;

#[derive(OpenApi)]
#[openapi(
    info(
        title = "polnlos",
        description = "Polarization-enhanced passive NLOS imaging: captures, reconstructions, camera."
    ),
    paths(
        routes::health,
        routes::metrics,
        routes::camera,
        routes::camera_settings,
        routes::post_capture,
        routes::list_captures,
        routes::get_capture,
        routes::capture_frames,
        routes::capture_mean,
        routes::capture_preview,
        routes::post_reconstruction,
        routes::list_reconstructions,
        routes::get_reconstruction,
        routes::reconstruction_image,
        routes::reconstruction_npy,
        routes::get_job,
        routes::events,
        routes::scenes,
        routes::scene_exposure,
    ),
    components(schemas(
        super::bodies::CaptureBody,
        super::bodies::ReconstructionBody,
        super::bodies::Health,
        super::bodies::Accepted,
        super::bodies::CaptureAccepted,
        super::bodies::ErrorBody,
        crate::camera::CameraSettings,
        crate::store::CaptureRecord,
        crate::store::ReconstructionRecord,
        crate::store::JobState,
        crate::measure::exposure::ExposureTarget,
        crate::measure::exposure::BlockExposure,
    ))
)]
struct Doc;

/// The OpenAPI document.
pub async fn spec() -> Json<utoipa::openapi::OpenApi> {
    Json(Doc::openapi())
}
