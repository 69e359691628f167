//! `GET /openapi.json`, generated from the handlers' annotations (utoipa).

use axum::Json;
use utoipa::{Modify, OpenApi};

use super::routes;

#[derive(OpenApi)]
#[openapi(
    modifiers(&Security, &Errors),
    info(
        title = "polnlos",
        description = "Polarization-enhanced passive NLOS imaging: captures, reconstructions, camera."
    ),
    paths(
        routes::health,
        routes::metrics,
        routes::camera,
        routes::camera_frame,
        routes::camera_settings,
        routes::post_capture,
        routes::list_captures,
        routes::get_capture,
        routes::capture_frames,
        routes::capture_mean,
        routes::capture_preview,
        routes::capture_progressive_image,
        routes::capture_progressive_steps,
        routes::post_calibration,
        routes::post_wall_calibration,
        routes::post_reconstruction,
        routes::list_reconstructions,
        routes::get_reconstruction,
        routes::reconstruction_image,
        routes::reconstruction_npy,
        routes::get_job,
        routes::cancel_job,
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
        super::bodies::ProgressiveBody,
        super::bodies::CalibrationBody,
        crate::daemon::GeometryCalibration,
        super::bodies::WallCalibrationBody,
        super::bodies::SourcePositionBody,
        crate::daemon::WallCalibration,
        crate::daemon::FittedPosition,
        crate::daemon::ProgressiveStep,
        crate::camera::CameraSettings,
        crate::camera::SettingsChange,
        crate::store::CaptureRecord,
        crate::store::ReconstructionRecord,
        crate::store::JobState,
        crate::store::CaptureKind,
        crate::daemon::CameraView,
        crate::camera::worker::CameraStatus,
        crate::camera::CameraInfo,
        crate::camera::Counters,
        crate::camera::SensorLimits,
        crate::camera::PixelFormat,
        crate::camera::TriggerMode,
        crate::measure::exposure::ExposureTarget,
        crate::measure::exposure::BlockExposure,
    ))
)]
struct Doc;

/// The bearer token scheme, required by every route but `/health` and the
/// page's static files (and reads, with `[http] public_reads`).
struct Security;

impl Modify for Security {
    fn modify(&self, doc: &mut utoipa::openapi::OpenApi) {
        use utoipa::openapi::security::{
            HttpAuthScheme, HttpBuilder, SecurityRequirement, SecurityScheme,
        };
        let components = doc.components.get_or_insert_with(Default::default);
        components.add_security_scheme(
            "bearer",
            SecurityScheme::Http(
                HttpBuilder::new()
                    .scheme(HttpAuthScheme::Bearer)
                    .description(Some(
                        "The token of [http] token_file; not needed when the daemon has none",
                    ))
                    .build(),
            ),
        );
        doc.security = Some(vec![SecurityRequirement::new(
            "bearer",
            Vec::<String>::new(),
        )]);
    }
}

/// Errors every route can answer (the guard's and the extractors'), and the
/// JSON body of every error response.
struct Errors;

impl Modify for Errors {
    fn modify(&self, doc: &mut utoipa::openapi::OpenApi) {
        use utoipa::openapi::{ContentBuilder, Ref, ResponseBuilder};
        let error = || {
            ContentBuilder::new()
                .schema(Some(Ref::from_schema_name("ErrorBody")))
                .build()
        };
        let common = [
            ("400", "A query string, path or body that cannot be read"),
            ("401", "The bearer token is missing or wrong"),
            ("403", "A foreign Host or Origin header"),
            ("414", "The request target is over 8 KiB"),
            ("431", "Over 64 header lines or 16 KiB of headers"),
            ("500", "The daemon failed (the detail says where)"),
        ];
        for item in doc.paths.paths.values_mut() {
            let ops = [
                &mut item.get,
                &mut item.put,
                &mut item.post,
                &mut item.delete,
            ];
            for op in ops.into_iter().flatten() {
                for (code, what) in common {
                    op.responses
                        .responses
                        .entry(code.to_string())
                        .or_insert_with(|| {
                            ResponseBuilder::new()
                                .description(what)
                                .content("application/json", error())
                                .build()
                                .into()
                        });
                }
                for (code, r) in op.responses.responses.iter_mut() {
                    if code.as_str() >= "400" {
                        if let utoipa::openapi::RefOr::T(r) = r {
                            r.content
                                .entry("application/json".into())
                                .or_insert_with(error);
                        }
                    }
                }
            }
        }
    }
}

/// The OpenAPI document.
pub async fn spec() -> Json<utoipa::openapi::OpenApi> {
    Json(Doc::openapi())
}
