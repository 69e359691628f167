//! Captures: submit, list, read, delete, and their files (frames, mean, dark, variance, preview, progressive steps).

use super::*;

/// Queues a capture.
#[utoipa::path(post, path = "/captures", request_body = CaptureBody, responses((status = 202, body = CaptureAccepted, description = "Queued; Location names the capture; the body echoes every setting it will use"), (status = 404, description = "Unknown scene"), (status = 422, description = "Out of range"), (status = 429, description = "Queue full"), (status = 507, description = "Its files would not fit on the disk")))]
pub async fn post_capture(
    State(d): St,
    ApiJson(b): ApiJson<CaptureBody>,
) -> Result<Response, ApiError> {
    let (id, req) = d.requests().submit_capture(b).await?;
    Ok(accepted("capture", id, CaptureAccepted::new(id, &req)))
}

/// Imports a measurement or a photo taken elsewhere as a done capture of
/// one pose of a scene: a `.npy` of `[rows]` or `[rows, C]` in the scene's
/// row order (the pose's blocks), or a 1- or 3-channel 8/16-bit TIFF or PNG
/// sampled through the pose's homography (`bayer` for a raw colour frame).
/// Its reconstruction fits the gain and background (`radiometry`).
#[utoipa::path(post, path = "/captures/import", params(ImportQuery), request_body(content = Vec<u8>, content_type = "application/octet-stream", description = "The file itself: .npy, TIFF or PNG (told by its first bytes)"), responses((status = 201, body = CaptureRecord, description = "Stored; Location names the capture"), (status = 404, body = ErrorBody, description = "Unknown scene"), (status = 413, body = ErrorBody, description = "Over [queue] max_import_mib"), (status = 422, body = ErrorBody, description = "Unknown pose, a file that does not fit the pose's blocks, or not .npy, TIFF or PNG"), (status = 507, body = ErrorBody, description = "It would not fit on the disk")))]
pub async fn import_capture(
    State(d): St,
    query: Result<Query<ImportQuery>, ApiError>,
    body: Result<axum::body::Bytes, axum::extract::rejection::BytesRejection>,
) -> Result<Response, ApiError> {
    // The query's error is answered after the body is read: a refusal sent
    // while the client still writes a large file cuts its connection, and
    // the client sees a broken pipe instead of the answer.
    let Query(q) = query?;
    let bytes = body.map_err(|r| match r.status() {
        StatusCode::PAYLOAD_TOO_LARGE => ApiError::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            "body_too_large",
            format!(
                "the file is over the import limit of {} MiB ([queue] max_import_mib)",
                d.config().queue.max_import_mib
            ),
        ),
        s => ApiError::new(s, "bad_request", r.body_text()),
    })?;
    if bytes.is_empty() {
        return Err(ApiError::invalid(
            "the body is empty: send the file (.npy, TIFF or PNG) as the body",
        ));
    }
    let record = tokio::task::spawn_blocking(move || d.requests().import_capture(&q, &bytes))
        .await
        .map_err(|e| ApiError::internal(e.to_string()))??;
    let location = format!("/captures/{}", record.id);
    Ok((
        StatusCode::CREATED,
        [(header::LOCATION, location)],
        Json(record),
    )
        .into_response())
}

/// Captures, newest first.
#[utoipa::path(get, path = "/captures", params(Page), responses((status = 200, body = [CaptureRecord], headers(("polnlos-unreadable" = String, description = "Ids of this page's rows the catalogue could not read (left out of the array; the daemon's log says why)")))))]
pub async fn list_captures(State(d): St, Query(p): Query<Page>) -> Result<Response, ApiError> {
    let (limit, offset) = p.get()?;
    let mut page = d.store().captures(limit, offset)?;
    page.records
        .iter_mut()
        .for_each(|c| c.progressive = has_steps(&d, c.id));
    Ok(listing(page))
}

/// Whether capture `id`'s folder holds its progressive steps.
fn has_steps(d: &Daemon, id: i64) -> bool {
    d.store()
        .capture_dir(id)
        .join(crate::daemon::PROGRESSIVE_STEPS)
        .is_file()
}

/// One capture.
#[utoipa::path(get, path = "/captures/{id}", params(("id" = String, Path, description = "The capture's id, a positive whole number")), responses((status = 200, body = CaptureRecord), (status = 404, description = "No such capture")))]
pub async fn get_capture(
    State(d): St,
    Path(id): Path<String>,
) -> Result<Json<CaptureRecord>, ApiError> {
    let mut c = d.store().capture(parse_id(&id, "capture")?)?;
    c.progressive = has_steps(&d, c.id);
    Ok(Json(c))
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
    let reconstructions = tokio::task::spawn_blocking(move || {
        d.requests().delete_capture(id, q.with_reconstructions)
    })
    .await
    .map_err(|e| ApiError::internal(e.to_string()))??;
    Ok(Json(Deleted {
        capture: Some(id),
        reconstructions,
    }))
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

/// An imported capture's measurement, .npy (`[n]` or `[n, C]`, the pose's
/// rows in the scene's row order, NaN where not measured).
#[utoipa::path(get, path = "/captures/{id}/measurement.npy", params(("id" = String, Path, description = "The capture's id, a positive whole number")), responses((status = 200, content_type = "application/octet-stream", description = "The measurement"), (status = 404, body = ErrorBody, description = "No such capture, or it was not imported")))]
pub async fn capture_measurement(
    State(d): St,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    capture_file(
        &d,
        &id,
        CaptureFiles::MEASUREMENT,
        "application/octet-stream",
    )
    .await
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
