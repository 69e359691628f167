//! The HTTP API: axum routes over the daemon's typed state, nothing else.
//!
//! Errors are JSON `{ "error": code, "detail": text }` with the right status,
//! whatever went wrong (a bad query string, a wrong method, an oversized
//! header); jobs answer 202 with a `Location`. Every request passes
//! `guard`: size limits, the `Host`/`Origin` checks, and the bearer token
//! when one is set. Request bodies are size- and time-limited; [`serve()`] caps
//! connections and header time; [`run`] serves a daemon until shut down.

pub mod bodies;
mod error;
mod extract;
mod guard;
mod openapi;
mod routes;
pub(crate) mod serve;
mod web;

use std::sync::Arc;
use std::time::Duration;

use axum::extract::State;
use axum::middleware;
use axum::routing::get;
use axum::Router;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

pub(crate) use error::ApiError;
pub use serve::{run, serve};

use crate::daemon::Daemon;

/// The router for a running daemon.
pub fn router(d: Arc<Daemon>) -> Router {
    let limit = d.config().queue.max_body_bytes;
    let import_limit = usize::try_from(d.config().queue.max_import_mib << 20).unwrap_or(usize::MAX);
    let body_timeout = Duration::from_secs_f64(d.config().http.body_timeout_s);
    let (app, doc) = all_routes(import_limit).split_for_parts();
    let doc = Arc::new(openapi::finish(doc));
    // The document itself is served beside the routes it documents, not among them.
    app.route(
        "/openapi.json",
        get(move |State(d): State<Arc<Daemon>>| openapi::spec(d, doc.clone())),
    )
    .fallback(routes::not_found)
    .method_not_allowed_fallback(routes::method_not_allowed)
    .layer(tower_http::timeout::RequestBodyTimeoutLayer::new(
        body_timeout,
    ))
    .layer(axum::extract::DefaultBodyLimit::max(limit))
    .layer(middleware::from_fn_with_state(
        guard::Guard::new(d.clone()),
        guard::guard,
    ))
    .layer(
        tower_http::trace::TraceLayer::new_for_http()
            .make_span_with(request_span)
            .on_request(())
            .on_response(answered)
            .on_body_chunk(())
            .on_eos(())
            .on_failure(()),
    )
    .layer(middleware::from_fn_with_state(
        Arc::new(std::sync::atomic::AtomicU64::new(1)),
        request_id,
    ))
    .with_state(d)
}

/// A request's number in this daemon's run (from 1), in its log lines and
/// its answer's `x-request-id` header.
#[derive(Debug, Clone, Copy)]
struct RequestId(u64);

/// Numbers each request and answers with its number (`x-request-id`).
///
/// Why: a user who reports an answer can name the log lines of its request.
async fn request_id(
    State(next_id): State<Arc<std::sync::atomic::AtomicU64>>,
    mut req: axum::extract::Request,
    next: middleware::Next,
) -> axum::response::Response {
    let id = next_id.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    req.extensions_mut().insert(RequestId(id));
    let mut res = next.run(req).await;
    res.headers_mut()
        .insert("x-request-id", axum::http::HeaderValue::from(id));
    res
}

/// A request's span: `request{id method path}`, around what its handler logs.
///
/// Why: a bench PC's log must say which request a job line or a refusal
/// came from.
fn request_span(req: &axum::http::Request<axum::body::Body>) -> tracing::Span {
    let id = req.extensions().get::<RequestId>().map_or(0, |r| r.0);
    tracing::info_span!("request", id, method = %req.method(), path = %req.uri().path())
}

/// One access-log line per answer, with the request's span (`id`,
/// `method`, `path`) and structured `status` and `latency_ms`: a refusal
/// (4xx) as a warning, a server error as an error, the rest at info.
///
/// Why: a bench PC's log must account for every request (the page's
/// polls too); `RUST_LOG=info,polnlos::api=warn` keeps only the failures.
fn answered(res: &axum::http::Response<axum::body::Body>, latency: Duration, _: &tracing::Span) {
    let status = res.status();
    let latency_ms = (latency.as_secs_f64() * 1e4).round() / 10.0;
    let code = status.as_u16();
    if status.is_server_error() {
        tracing::error!(status = code, latency_ms, "failed");
    } else if status.is_client_error() {
        tracing::warn!(status = code, latency_ms, "refused");
    } else {
        tracing::info!(status = code, latency_ms, "answered");
    }
}

/// Every route, each declared once. An API route is one `routes!` line
/// naming its handler, whose `#[utoipa::path]` gives the method and path
/// axum routes and the operation `/openapi.json` documents, so the two
/// cannot drift apart; handlers of one path share a line (a line with
/// several paths would route every handler at each of them). The page and
/// its files are plain routes: not API, so not in the document.
/// `import_limit` bounds the one route whose body is a file, not JSON.
fn all_routes(import_limit: usize) -> OpenApiRouter<Arc<Daemon>> {
    let (schemas, paths, import) = routes!(routes::import_capture);
    let import = (
        schemas,
        paths,
        import.layer(axum::extract::DefaultBodyLimit::max(import_limit)),
    );
    let (schemas, paths, scene_routes) = routes!(routes::scenes, routes::post_scene);
    let scene_routes = (
        schemas,
        paths,
        scene_routes.layer(axum::extract::DefaultBodyLimit::max(
            crate::daemon::runtime::scene_registry::MAX_SCENE_BYTES,
        )),
    );
    let (schemas, paths, scene_file) = routes!(routes::put_scene, routes::delete_scene);
    let scene_file = (
        schemas,
        paths,
        scene_file.layer(axum::extract::DefaultBodyLimit::max(
            crate::daemon::runtime::scene_registry::MAX_SCENE_BYTES,
        )),
    );
    OpenApiRouter::with_openapi(openapi::base())
        .route("/", get(web::index))
        .route("/app.js", get(web::app))
        .route("/style.css", get(web::style))
        .route("/api", get(web::api))
        .route("/api.js", get(web::api_js))
        .route("/bench/{name}", get(web::chart))
        .routes(routes!(routes::health))
        .routes(routes!(routes::metrics))
        .routes(routes!(routes::camera))
        .routes(routes!(routes::camera_frame))
        .routes(routes!(routes::camera_settings))
        .routes(routes!(routes::mount))
        .routes(routes!(routes::mount_zero))
        .routes(routes!(routes::stage))
        .routes(routes!(routes::light))
        .routes(routes!(
            routes::post_live,
            routes::get_live,
            routes::delete_live
        ))
        .routes(routes!(routes::live_image))
        .routes(routes!(routes::live_track))
        .routes(routes!(routes::post_plan, routes::list_plans))
        .routes(routes!(routes::get_plan, routes::cancel_plan))
        .routes(routes!(routes::continue_plan))
        .routes(routes!(routes::post_capture, routes::list_captures))
        .routes(import)
        .routes(routes!(routes::get_capture, routes::delete_capture))
        .routes(routes!(routes::capture_frames))
        .routes(routes!(routes::capture_mean))
        .routes(routes!(routes::capture_dark))
        .routes(routes!(routes::capture_variance))
        .routes(routes!(routes::capture_preview))
        .routes(routes!(routes::capture_measurement))
        .routes(routes!(routes::capture_progressive_image))
        .routes(routes!(routes::capture_progressive_steps))
        .routes(routes!(routes::post_calibration, routes::list_calibrations))
        .routes(routes!(routes::post_wall_calibration))
        .routes(routes!(routes::post_colour_calibration))
        .routes(routes!(
            routes::post_scene_calibration,
            routes::list_scene_calibrations
        ))
        .routes(routes!(
            routes::get_scene_calibration,
            routes::delete_scene_calibration
        ))
        .routes(routes!(
            routes::post_reconstruction,
            routes::list_reconstructions
        ))
        .routes(routes!(
            routes::get_reconstruction,
            routes::delete_reconstruction
        ))
        .routes(routes!(routes::reconstruction_image))
        .routes(routes!(routes::reconstruction_truth))
        .routes(routes!(routes::reconstruction_npy))
        .routes(routes!(routes::reconstruction_measurement))
        .routes(routes!(routes::reconstruction_report))
        .routes(routes!(routes::get_job, routes::cancel_job))
        .routes(routes!(routes::events))
        .routes(scene_routes)
        .routes(scene_file)
        .routes(routes!(routes::scene_exposure))
        .routes(routes!(routes::scene_wall))
}
