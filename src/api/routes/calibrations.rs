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

/// Fits the scene's geometry to its captures as a job (`scene-fit-<n>` on
/// `/events`, cancelled by `DELETE /jobs/scene-fit-<n>`); once done, every
/// later reconstruction of the scene uses the fitted geometry and says so.
#[utoipa::path(post, path = "/calibrations/scene", request_body = crate::daemon::SceneFitBody, responses((status = 202, body = Accepted, description = "Started; Location names the scene calibration"), (status = 404, body = ErrorBody, description = "No such scene or capture"), (status = 409, body = ErrorBody, description = "Another scene calibration is running"), (status = 422, body = ErrorBody, description = "Not done light captures of the scene, a row unmeasured, an unknown freedom or a value out of range")))]
pub async fn post_scene_calibration(
    State(d): St,
    ApiJson(b): ApiJson<crate::daemon::SceneFitBody>,
) -> Result<Response, ApiError> {
    let row = tokio::task::spawn_blocking(move || d.procedures().fit_scene(&b))
        .await
        .map_err(|e| ApiError::internal(e.to_string()))??;
    let location = format!("/calibrations/scene/{}", row.id);
    let body = Accepted {
        id: row.id,
        state: "queued",
        job: format!("scene-fit-{}", row.id),
    };
    Ok((
        StatusCode::ACCEPTED,
        [(header::LOCATION, location)],
        Json(body),
    )
        .into_response())
}

/// Scene calibrations, newest first; each scene serves the geometry of its
/// newest done one (`GET /scenes` names it).
#[utoipa::path(get, path = "/calibrations/scene", responses((status = 200, body = [crate::store::SceneFitRow])))]
pub async fn list_scene_calibrations(
    State(d): St,
) -> Result<Json<Vec<crate::store::SceneFitRow>>, ApiError> {
    Ok(Json(d.store().scene_fits()?))
}

/// One scene calibration: its state, and when done the fitted offsets with
/// their uncertainties and the placed scene file.
#[utoipa::path(get, path = "/calibrations/scene/{id}", params(("id" = String, Path, description = "The scene calibration's id, a positive whole number")), responses((status = 200, body = crate::store::SceneFitRow), (status = 404, body = ErrorBody, description = "No such scene calibration")))]
pub async fn get_scene_calibration(
    State(d): St,
    Path(id): Path<String>,
) -> Result<Json<crate::store::SceneFitRow>, ApiError> {
    Ok(Json(
        d.store().scene_fit(parse_id(&id, "scene calibration")?)?,
    ))
}

/// Deletes an ended scene calibration; its scene serves the newest done
/// one left, or its file's geometry.
#[utoipa::path(delete, path = "/calibrations/scene/{id}", params(("id" = String, Path, description = "The scene calibration's id, a positive whole number")), responses((status = 204, description = "Deleted"), (status = 404, body = ErrorBody, description = "No such scene calibration"), (status = 409, body = ErrorBody, description = "Queued or running: cancel it first")))]
pub async fn delete_scene_calibration(
    State(d): St,
    Path(id): Path<String>,
) -> Result<StatusCode, ApiError> {
    let id = parse_id(&id, "scene calibration")?;
    tokio::task::spawn_blocking(move || d.procedures().delete_scene_fit(id))
        .await
        .map_err(|e| ApiError::internal(e.to_string()))??;
    Ok(StatusCode::NO_CONTENT)
}
