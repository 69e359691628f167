//! The camera: its state, its latest or live frame (grey, colour, Stokes views) and its settings.

use super::*;

/// Camera identity, ranges, counters, connection state, and its settings as
/// read back from it now (during a capture: as that capture set them, with
/// `busy` naming the capture).
#[utoipa::path(get, path = "/camera", responses((status = 200, body = crate::daemon::CameraView, description = "Camera state")))]
pub async fn camera(State(d): St) -> Json<crate::daemon::CameraView> {
    Json(d.camera().now().await)
}

/// `?live=true&stretch=true` of `GET /camera/frame.png`.
#[derive(Debug, Default, serde::Deserialize, utoipa::IntoParams)]
#[serde(deny_unknown_fields)]
pub struct FrameQuery {
    /// Take a fresh frame when no capture has the camera (the live view);
    /// while a capture runs, its latest frame either way.
    #[serde(default)]
    live: bool,
    /// Auto-contrast: the 0.5th..99.5th percentile to black..white (a
    /// crossed-polarizer frame peaks at a few percent of full scale).
    #[serde(default)]
    stretch: bool,
    /// On a polarizer-mosaic camera: `raw` (the mosaic as read out), `s0`
    /// (intensity), `dolp` (degree of linear polarization) or `aolp` (its
    /// angle), the last three at half resolution.
    #[serde(default)]
    #[param(value_type = Option<String>)]
    view: crate::measure::mosaic::View,
}

/// The latest frame (with `live=true`, a fresh one when the camera is idle),
/// as a 16-bit PNG scaled to full scale or stretched; its levels (histogram,
/// peak, saturated share, stretch) in the `polnlos-levels` header as JSON.
#[utoipa::path(get, path = "/camera/frame.png", params(FrameQuery), responses((status = 200, content_type = "image/png", description = "The frame; header polnlos-levels: its levels as JSON", headers(("polnlos-levels" = String, description = "JSON: full_scale, histogram (64 bins from histogram_low to histogram_high DN), histogram_low, histogram_high, peak, saturated, low, high (the stretch)"))), (status = 404, body = ErrorBody, description = "No frame yet (no camera, or none delivered)")))]
pub async fn camera_frame(State(d): St, Query(q): Query<FrameQuery>) -> Result<Response, ApiError> {
    let frame = if q.live {
        d.camera().live_frame().await
    } else {
        d.camera().latest_frame()
    };
    let frame = frame.ok_or_else(|| {
        ApiError::not_found("no frame yet: the camera has delivered none (is it connected?)")
    })?;
    if q.view == crate::measure::mosaic::View::Colour {
        return colour_frame(&d, frame, q.stretch).await;
    }
    // The Stokes views read the mosaic the camera's settings say the frame holds.
    let mosaic = match q.view {
        crate::measure::mosaic::View::Raw => None,
        view => {
            let settings = d.camera().status().info.map(|i| i.settings);
            let layout = settings.and_then(|s| s.pixel_format.mosaic()).ok_or_else(|| {
                ApiError::invalid(format!(
                    "view={view:?} is for a polarizer-mosaic camera; this camera reads out {} (use view=raw, or a polarization pixel_format)",
                    settings.map_or("no frames yet".to_string(), |s| s.pixel_format.name().to_string())
                ))
            })?;
            let region = settings.map_or([0, 0, 0, 0], |s| s.region);
            Some((layout, [region[0], region[1]], view))
        }
    };
    let (png, levels) = tokio::task::spawn_blocking(move || {
        let (width, height, pixels, bits) = match mosaic {
            Some((layout, offset, view)) => crate::measure::mosaic::view(
                &frame.pixels,
                (frame.width, frame.height, frame.bits),
                layout,
                offset,
                view,
            ),
            None => (frame.width, frame.height, frame.pixels.to_vec(), frame.bits),
        };
        let levels = crate::measure::levels::levels(&pixels, bits)
            .ok_or_else(|| "the frame has no pixels".to_string())?;
        let shown = crate::measure::levels::display_u16(&pixels, &levels, q.stretch);
        let png =
            crate::files::image::encode_png16(width, height, &shown).map_err(|e| e.to_string())?;
        Ok::<_, String>((png, levels))
    })
    .await
    .map_err(|e| ApiError::internal(e.to_string()))?
    .map_err(ApiError::internal)?;
    live_png(png, &levels)
}

/// `GET /camera/frame.png?view=colour`: a colour camera's raw `frame` in
/// colour, one RGB pixel per 2x2 cell, every channel on one stretch; 422
/// for a camera without a Bayer filter.
async fn colour_frame(
    d: &Daemon,
    frame: Arc<crate::camera::RawFrame>,
    stretch: bool,
) -> Result<Response, ApiError> {
    let settings = d.camera().status().info.map(|i| i.settings);
    let pattern = settings.and_then(|s| s.pixel_format.bayer()).ok_or_else(|| {
        ApiError::invalid(format!(
            "view=colour is for a colour camera reading out its raw Bayer frames; this camera reads out {} (use view=raw, or a Bayer pixel_format)",
            settings.map_or("no frames yet".to_string(), |s| s.pixel_format.name().to_string())
        ))
    })?;
    let region = settings.map_or([0, 0, 0, 0], |s| s.region);
    let (png, levels) = tokio::task::spawn_blocking(move || {
        let (w, h, rgb) = crate::measure::colour::cells_rgb(
            &frame.pixels,
            (frame.width, frame.height),
            pattern,
            [region[0], region[1]],
        );
        let levels = crate::measure::levels::levels(&rgb, frame.bits)
            .ok_or_else(|| "the frame has no whole 2x2 cell".to_string())?;
        let shown = crate::measure::levels::display_u16(&rgb, &levels, stretch);
        let png = crate::files::image::encode_png_rgb16(w, h, &shown).map_err(|e| e.to_string())?;
        Ok::<_, String>((png, levels))
    })
    .await
    .map_err(|e| ApiError::internal(e.to_string()))?
    .map_err(ApiError::internal)?;
    live_png(png, &levels)
}

/// A live-view PNG with its `levels` in the `polnlos-levels` header, never cached.
fn live_png(png: Vec<u8>, levels: &crate::measure::levels::Levels) -> Result<Response, ApiError> {
    let levels = serde_json::to_string(levels).map_err(|e| ApiError::internal(e.to_string()))?;
    Ok((
        [
            (header::CONTENT_TYPE, "image/png".to_string()),
            (header::CACHE_CONTROL, "no-store".to_string()),
            (header::HeaderName::from_static("polnlos-levels"), levels),
        ],
        png,
    )
        .into_response())
}

/// Changes the capture defaults (any subset of the settings; the rest keep
/// theirs) and applies them to the camera now (queued captures keep their
/// own). 409 while a capture has the camera.
#[utoipa::path(put, path = "/camera/settings", request_body = SettingsBody, responses((status = 200, body = crate::camera::CameraInfo, description = "Applied; the camera's description with its settings read back"), (status = 409, description = "A capture is running"), (status = 422, description = "Out of range"), (status = 503, description = "No camera")))]
pub async fn camera_settings(
    State(d): St,
    ApiJson(s): ApiJson<SettingsBody>,
) -> Result<Json<crate::camera::CameraInfo>, ApiError> {
    Ok(Json(d.camera().put_settings(s.change).await?))
}
