//! Scenes: the list, adding, replacing and deleting one, each block's
//! exposure, and where each pose sees the wall.

use super::*;
use crate::api::extract::ApiToml;
use crate::daemon::runtime::scene_registry::SceneChangeError;
use crate::daemon::runtime::scenes::SceneListing;

/// Every scene the daemon serves, and every scene file that does not load
/// with its error.
#[utoipa::path(get, path = "/scenes", responses((status = 200, body = [SceneListing], description = "Scenes by name")))]
pub async fn scenes(State(d): St) -> Json<Vec<SceneListing>> {
    Json(d.scenes().listing())
}

/// The query of `POST /scenes`.
#[derive(Debug, serde::Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct SceneQuery {
    /// The new scene's name: 1 to 64 letters, digits, `-`, `_` or `.`.
    pub name: String,
}

/// Adds a scene from its file (TOML, docs/MODEL.md), kept in the data
/// directory and served at once; relative mesh paths are read from the
/// data directory's `scenes/`.
#[utoipa::path(post, path = "/scenes", params(SceneQuery), request_body(content = String, content_type = "application/toml", description = "The scene file"), responses((status = 201, body = SceneListing, description = "Served; Location names the scene"), (status = 400, body = ErrorBody, description = "No name"), (status = 409, body = ErrorBody, description = "A scene of that name exists"), (status = 413, body = ErrorBody, description = "Over 256 KiB"), (status = 415, body = ErrorBody, description = "Not application/toml"), (status = 422, body = ErrorBody, description = "Not a valid scene file (the error names the line), or a bad name"), (status = 500, body = ErrorBody, description = "The data directory could not be written")))]
pub async fn post_scene(
    State(d): St,
    query: Result<Query<SceneQuery>, ApiError>,
    ApiToml(text): ApiToml,
) -> Result<Response, ApiError> {
    let Query(q) = query?;
    let name = q.name.clone();
    let listing = tokio::task::spawn_blocking(move || d.scene_registry().add(&q.name, &text))
        .await
        .map_err(|e| ApiError::internal(e.to_string()))?
        .map_err(scene_change)?;
    let location = format!("/scenes/{name}");
    Ok((
        StatusCode::CREATED,
        [(header::LOCATION, location)],
        Json(listing),
    )
        .into_response())
}

/// Replaces a scene with a new file (TOML), kept in the data directory; a
/// job that started before keeps the old one. Relative mesh paths are
/// read from the folder of the file it replaces.
#[utoipa::path(put, path = "/scenes/{name}", params(("name" = String, Path, description = "Scene name")), request_body(content = String, content_type = "application/toml", description = "The scene file"), responses((status = 200, body = SceneListing, description = "Served"), (status = 404, body = ErrorBody, description = "Unknown scene"), (status = 413, body = ErrorBody, description = "Over 256 KiB"), (status = 415, body = ErrorBody, description = "Not application/toml"), (status = 422, body = ErrorBody, description = "Not a valid scene file (the error names the line)"), (status = 500, body = ErrorBody, description = "The data directory could not be written")))]
pub async fn put_scene(
    State(d): St,
    Path(name): Path<String>,
    ApiToml(text): ApiToml,
) -> Result<Json<SceneListing>, ApiError> {
    let listing = tokio::task::spawn_blocking(move || d.scene_registry().replace(&name, &text))
        .await
        .map_err(|e| ApiError::internal(e.to_string()))?
        .map_err(scene_change)?;
    Ok(Json(listing))
}

/// Deletes a posted scene; a job that started before keeps it.
#[utoipa::path(delete, path = "/scenes/{name}", params(("name" = String, Path, description = "Scene name")), responses((status = 204, description = "Deleted"), (status = 404, body = ErrorBody, description = "Unknown scene"), (status = 409, body = ErrorBody, description = "A built-in scene or a file of scene_files"), (status = 500, body = ErrorBody, description = "The data directory could not be written")))]
pub async fn delete_scene(State(d): St, Path(name): Path<String>) -> Result<StatusCode, ApiError> {
    tokio::task::spawn_blocking(move || d.scene_registry().delete(&name))
        .await
        .map_err(|e| ApiError::internal(e.to_string()))?
        .map_err(scene_change)?;
    Ok(StatusCode::NO_CONTENT)
}

/// A scene change's error as its answer.
fn scene_change(e: SceneChangeError) -> ApiError {
    let status = match &e {
        SceneChangeError::Exists { .. } | SceneChangeError::NotPosted { .. } => {
            StatusCode::CONFLICT
        }
        SceneChangeError::Unknown { .. } => StatusCode::NOT_FOUND,
        SceneChangeError::Store { .. } | SceneChangeError::Write { .. } => {
            StatusCode::INTERNAL_SERVER_ERROR
        }
        _ => StatusCode::UNPROCESSABLE_ENTITY,
    };
    let code = match status {
        StatusCode::CONFLICT => "conflict",
        StatusCode::NOT_FOUND => "not_found",
        StatusCode::INTERNAL_SERVER_ERROR => "internal",
        _ => "invalid_request",
    };
    ApiError::new(status, code, e.to_string())
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
