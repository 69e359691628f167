//! Scenes: their names, each block's exposure, and where each pose sees the wall.

use super::*;

/// Scene names the daemon knows.
#[utoipa::path(get, path = "/scenes", responses((status = 200, body = [String], description = "Scene names")))]
pub async fn scenes(State(d): St) -> Json<Vec<String>> {
    Json(d.scenes().names())
}

/// The planned exposure and frame count of every (pose, angle) block of a scene.
#[utoipa::path(get, path = "/scenes/{name}/exposure", params(("name" = String, Path, description = "Scene name"), TargetQuery), responses((status = 200, body = [BlockExposure]), (status = 404, description = "Unknown scene"), (status = 422, description = "No calibration, or a target out of range")))]
pub async fn scene_exposure(
    State(d): St,
    Path(name): Path<String>,
    Query(q): Query<TargetQuery>,
) -> Result<Json<Vec<BlockExposure>>, ApiError> {
    let target = q.target();
    let blocks = tokio::task::spawn_blocking(move || d.requests().block_exposures(&name, &target))
        .await
        .map_err(|e| ApiError::internal(e.to_string()))??;
    Ok(Json(blocks))
}

/// Where each pose of a scene sees its wall, in sensor pixels: the live
/// view zooms onto it.
#[utoipa::path(get, path = "/scenes/{name}/wall", params(("name" = String, Path, description = "Scene name")), responses((status = 200, body = [crate::daemon::runtime::scenes::WallView]), (status = 404, body = ErrorBody, description = "Unknown scene")))]
pub async fn scene_wall(
    State(d): St,
    Path(name): Path<String>,
) -> Result<Json<Vec<crate::daemon::runtime::scenes::WallView>>, ApiError> {
    Ok(Json(
        d.scenes()
            .wall_views(&name)
            .map_err(crate::daemon::RequestError::from)?,
    ))
}
