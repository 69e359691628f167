//! The rig's devices as the daemon reads them back, and the mount's zero sweep.

use super::*;

/// The rotation mount that turns the polarizer: its kind and port, the angle
/// read from it now (as last read while a capture turns it), and its last error.
#[utoipa::path(get, path = "/mount", responses((status = 200, body = crate::rig::mount::MountView, description = "Mount state")))]
pub async fn mount(State(d): St) -> Json<crate::rig::mount::MountView> {
    Json(d.rig().mount_view().await)
}

/// The relay that switches the hidden scene's light for dark frames: its
/// kind, port and relay, whether the light was on when last read, and its last error.
#[utoipa::path(get, path = "/light", responses((status = 200, body = crate::rig::relay::LightView, description = "Light switch state")))]
pub async fn light(State(d): St) -> Json<crate::rig::relay::LightView> {
    Json(d.rig().light_view())
}

/// The camera stage that moves the camera between poses: its kind, the pose
/// it last reached, the position read back, and its last error.
#[utoipa::path(get, path = "/stage", responses((status = 200, body = crate::rig::stage::StageView, description = "Stage state")))]
pub async fn stage(State(d): St) -> Json<crate::rig::stage::StageView> {
    Json(d.rig().stage_view())
}

/// Finds the mount angle at which the polarizer is crossed: sweeps the
/// mount around its zero with the camera at `pose`, fits the minimum of the
/// polarizer's intensity law to the wall's mean light, and makes it the
/// zero (kept in the data directory). Holds the camera like a capture.
#[utoipa::path(post, path = "/mount/zero", request_body = crate::daemon::ZeroBody, responses((status = 200, body = crate::daemon::ZeroFit, description = "The zero found, now in force, and the sweep"), (status = 404, description = "Unknown scene"), (status = 422, description = "No mount, a value out of range, or no minimum in the sweep"), (status = 503, description = "No camera, the camera stayed busy for 5 s, or the mount did not turn")))]
pub async fn mount_zero(
    State(d): St,
    ApiJson(b): ApiJson<crate::daemon::ZeroBody>,
) -> Result<Json<crate::daemon::ZeroFit>, ApiError> {
    Ok(Json(d.procedures().calibrate_mount_zero(b).await?))
}
