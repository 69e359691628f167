//! Reconstructions: submit, list, read, delete, and their files (image, truth, arrays, report).

use super::*;
use crate::api::bodies::ReconstructionBody;

/// Deletes an ended reconstruction: its catalogue row and its files.
#[utoipa::path(delete, path = "/reconstructions/{id}", params(("id" = String, Path, description = "The reconstruction's id, a positive whole number")), responses((status = 200, body = Deleted, description = "Deleted, row and files"), (status = 404, description = "No such reconstruction"), (status = 409, description = "Queued or running")))]
pub async fn delete_reconstruction(
    State(d): St,
    Path(id): Path<String>,
) -> Result<Json<Deleted>, ApiError> {
    let id = parse_id(&id, "reconstruction")?;
    tokio::task::spawn_blocking(move || d.requests().delete_reconstruction(id))
        .await
        .map_err(|e| ApiError::internal(e.to_string()))??;
    Ok(Json(Deleted {
        capture: None,
        reconstructions: vec![id],
    }))
}

/// Queues a reconstruction.
#[utoipa::path(post, path = "/reconstructions", request_body = ReconstructionBody, responses((status = 202, body = Accepted, description = "Queued; Location names the reconstruction"), (status = 404, description = "Unknown scene or capture"), (status = 422, description = "Invalid"), (status = 429, description = "Queue full")))]
pub async fn post_reconstruction(
    State(d): St,
    ApiJson(b): ApiJson<ReconstructionBody>,
) -> Result<Response, ApiError> {
    let id = d.requests().submit_reconstruction(&b)?;
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
        .map_err(|e| ApiError::invalid(e.to_string()))?;
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
        d.scenes()
            .truth_png(&rec)
            .map_err(|e| ApiError::internal(e.to_string()))
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
