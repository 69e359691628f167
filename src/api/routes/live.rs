//! The live view: start it with a capture request, watch it, stop it.

use super::*;
use crate::daemon::runtime::live::LiveView;

/// Starts the live view: the camera repeats this capture request (`frames`
/// is the rolling window, 1 to 64; `progressive` sets λ, the truth and the
/// other blocks' captures) and each new window is reconstructed, while no
/// capture is queued; a running session is replaced. Results stream on
/// `/events` (`live`) and as `/live/image.png`. With `difference` each
/// window is reconstructed against a running background (what moves) and
/// the moving object is tracked (`/live/track.csv`). With `record` the
/// session's first `record.frames` frames are written, as they arrive, to a
/// new capture (`GET /live`'s `recording` names it), its disk reserved now.
#[utoipa::path(post, path = "/live", request_body = CaptureBody, responses((status = 202, body = LiveView, description = "Started; GET /live follows it"), (status = 404, body = ErrorBody, description = "Unknown scene, pose or dark capture"), (status = 422, body = ErrorBody, description = "A request the camera, the scene or the window cannot serve"), (status = 507, body = ErrorBody, description = "The recording's frames would not fit on the data directory's disk")))]
pub async fn post_live(
    State(d): St,
    ApiJson(b): ApiJson<CaptureBody>,
) -> Result<Response, ApiError> {
    let view = d.requests().start_live(b).await?;
    Ok((
        StatusCode::ACCEPTED,
        [(header::LOCATION, "/live".to_string())],
        Json(view),
    )
        .into_response())
}

/// The live view's state: running, paused by a capture, failed or off;
/// results so far, results per second, the median frame-to-result latency
/// and the newest result's numbers.
#[utoipa::path(get, path = "/live", responses((status = 200, body = LiveView)))]
pub async fn get_live(State(d): St) -> Json<LiveView> {
    Json(d.live().view())
}

/// Stops the live view (the camera is free for settings changes at once);
/// answers its last state, as `off`.
#[utoipa::path(delete, path = "/live", responses((status = 200, body = LiveView)))]
pub async fn delete_live(State(d): St) -> Json<LiveView> {
    Json(d.requests().stop_live())
}

/// The live view's newest image, 16-bit PNG on the scene grid, top row first.
#[utoipa::path(get, path = "/live/image.png", responses((status = 200, content_type = "image/png", description = "Newest live image"), (status = 404, body = ErrorBody, description = "No live result yet")))]
pub async fn live_image(State(d): St) -> Result<Response, ApiError> {
    let (nu, nv, values) = d.live().image().ok_or_else(|| {
        ApiError::not_found("the live view has no result yet (POST /live starts it)".to_string())
    })?;
    // A colour camera's image has red, green and blue per element.
    let colour = values.len() == 3 * nu * nv;
    // Shown as people look at it: the plane's top (+v) in the first row.
    let grid = crate::scene::Grid { nu, nv };
    let pixels =
        crate::files::image::unit_to_u16(&grid.to_top_first(&values, 1 + 2 * usize::from(colour)));
    let png = match colour {
        true => crate::files::image::encode_png_rgb16(nu, nv, &pixels),
        false => crate::files::image::encode_png16(nu, nv, &pixels),
    }
    .map_err(|e| ApiError::internal(format!("live image: {e}")))?;
    Ok(([(header::CONTENT_TYPE, "image/png")], Body::from(png)).into_response())
}

/// The track of the newest live session in difference mode, CSV: one row
/// per result (the newest 10,000), `time_s` (the window's mean frame
/// arrival, Unix seconds), `u_m`, `v_m` (the moving object's centroid on the
/// hidden-scene plane, metres) and `sigma_u_m`, `sigma_v_m` (its standard
/// deviations); the centroid's fields are empty when nothing moved. Kept
/// after `DELETE /live` until the next `POST /live`.
#[utoipa::path(get, path = "/live/track.csv", responses((status = 200, content_type = "text/csv", body = String, description = "The track, a header and one row per result")))]
pub async fn live_track(State(d): St) -> Response {
    (
        [(header::CONTENT_TYPE, "text/csv; charset=utf-8")],
        d.live().track_csv(),
    )
        .into_response()
}
