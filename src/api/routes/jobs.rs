//! Jobs by name (`capture-N`, `reconstruction-N`, `scene-fit-N`): their record, and cancelling one.

use super::*;

/// A job id `capture-<n>`, `reconstruction-<n>` or `scene-fit-<n>`, parsed.
fn parse_job(id: &str) -> Result<(JobKind, i64), ApiError> {
    let bad = || {
        ApiError::not_found(format!(
            "{id:?} is not a job id; jobs are capture-<n>, reconstruction-<n> or scene-fit-<n>"
        ))
    };
    let (kind, n) = id.rsplit_once('-').ok_or_else(bad)?;
    let n = n.parse::<i64>().ok().filter(|n| *n > 0).ok_or_else(bad)?;
    match kind {
        "capture" => Ok((JobKind::Capture, n)),
        "reconstruction" => Ok((JobKind::Reconstruction, n)),
        "scene-fit" => Ok((JobKind::SceneFit, n)),
        _ => Err(bad()),
    }
}

/// The record of a job, with its `job` id.
fn job_record(d: &Daemon, kind: JobKind, n: i64) -> Result<serde_json::Value, ApiError> {
    let v = match kind {
        JobKind::Capture => serde_json::to_value(d.store().capture(n)?),
        JobKind::Reconstruction => serde_json::to_value(d.store().reconstruction(n)?),
        JobKind::SceneFit => serde_json::to_value(d.store().scene_fit(n)?),
    };
    let mut v = v.map_err(|e| ApiError::internal(e.to_string()))?;
    v["job"] = serde_json::Value::String(format!("{}-{n}", kind.name()));
    Ok(v)
}

/// A job by id: `capture-<n>` or `reconstruction-<n>`.
#[utoipa::path(get, path = "/jobs/{id}", params(("id" = String, Path, description = "capture-<n>, reconstruction-<n> or scene-fit-<n>")), responses((status = 200, description = "The capture or reconstruction"), (status = 404, body = ErrorBody, description = "No such job")))]
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
#[utoipa::path(delete, path = "/jobs/{id}", params(("id" = String, Path, description = "capture-<n>, reconstruction-<n> or scene-fit-<n>")), responses((status = 200, description = "Cancelled: the job's record"), (status = 202, description = "Still stopping: the job's record"), (status = 404, body = ErrorBody, description = "No such job"), (status = 409, body = ErrorBody, description = "The job already ended")))]
pub async fn cancel_job(State(d): St, Path(id): Path<String>) -> Result<Response, ApiError> {
    let (kind, n) = parse_job(&id)?;
    let state = d.requests().cancel_job(kind, n).await?;
    let status = if state == JobState::Running {
        StatusCode::ACCEPTED
    } else {
        StatusCode::OK
    };
    Ok((status, Json(job_record(&d, kind, n)?)).into_response())
}
