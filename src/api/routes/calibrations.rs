//! Calibrations: the radiometric gain per scene, and fitting a pose or the wall from captures.

use super::*;

/// The radiometric gain of each scene that has one, as reconstructions
/// use it (and `polnlos measure --gain` takes it).
#[utoipa::path(get, path = "/calibrations", responses((status = 200, body = crate::daemon::Calibrations, description = "The gains in use, and each scene's colour calibration")))]
pub async fn list_calibrations(
    State(d): St,
) -> Result<Json<crate::daemon::Calibrations>, ApiError> {
    Ok(Json(d.procedures().calibrations()?))
}

/// Measures a colour camera's balance from a capture of a white or grey
/// field and stores it for the capture's scene: calibrated reconstructions
/// then divide each colour by its own gain.
#[utoipa::path(post, path = "/calibrations/colour", request_body = crate::api::bodies::ColourCalibrationBody, responses((status = 200, body = crate::daemon::ColourCalibration, description = "The balance measured and stored"), (status = 404, body = ErrorBody, description = "No such capture"), (status = 422, body = ErrorBody, description = "Not a done light capture from a colour camera, or a colour too dark or too noisy to calibrate")))]
pub async fn post_colour_calibration(
    State(d): St,
    ApiJson(b): ApiJson<crate::api::bodies::ColourCalibrationBody>,
) -> Result<Json<crate::daemon::ColourCalibration>, ApiError> {
    let r = tokio::task::spawn_blocking(move || d.procedures().calibrate_colour(b.capture))
        .await
        .map_err(|e| ApiError::internal(e.to_string()))??;
    Ok(Json(r))
}

/// Fits the pose of a target capture: its homography, reprojection error,
/// and the scene file rewritten with it.
#[utoipa::path(post, path = "/calibrations", request_body = crate::api::bodies::CalibrationBody, responses((status = 200, body = crate::daemon::GeometryCalibration, description = "The fitted pose and the scene file to review"), (status = 404, body = ErrorBody, description = "No such capture"), (status = 422, body = ErrorBody, description = "Not a done target capture, or the dots could not be found or identified")))]
pub async fn post_calibration(
    State(d): St,
    ApiJson(b): ApiJson<crate::api::bodies::CalibrationBody>,
) -> Result<Json<crate::daemon::GeometryCalibration>, ApiError> {
    let r = tokio::task::spawn_blocking(move || {
        d.procedures()
            .calibrate_geometry(b.capture, b.target.as_deref())
    })
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
    let positions = b
        .positions()
        .map_err(|e| ApiError::invalid(e.to_string()))?;
    let r =
        tokio::task::spawn_blocking(move || d.procedures().calibrate_wall(&b.scene, &positions))
            .await
            .map_err(|e| ApiError::internal(e.to_string()))??;
    Ok(Json(r))
}
