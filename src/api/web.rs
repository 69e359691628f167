//! The web page at `/` (sources in `web/`, built into the binary: no CDN,
//! works offline) and the bench charts it shows. The page itself holds no
//! data, so it is served without the token; it reads everything through
//! the same API and token as any client.

use axum::extract::Path;
use axum::http::header;
use axum::response::{IntoResponse, Response};

use super::ApiError;

const INDEX: &str = include_str!("../../web/index.html");
const APP: &str = include_str!("../../web/app.js");
const STYLE: &str = include_str!("../../web/style.css");
const API: &str = include_str!("../../web/api.html");
const API_JS: &str = include_str!("../../web/api.js");

/// The committed bench charts (`docs/bench`), by file name.
const CHARTS: &[(&str, &[u8])] = &[
    (
        "conditioning.png",
        include_bytes!("../../docs/bench/conditioning.png"),
    ),
    (
        "roughness.png",
        include_bytes!("../../docs/bench/roughness.png"),
    ),
    (
        "sampling.png",
        include_bytes!("../../docs/bench/sampling.png"),
    ),
    ("active.png", include_bytes!("../../docs/bench/active.png")),
    (
        "rendered.png",
        include_bytes!("../../docs/bench/rendered.png"),
    ),
    (
        "speed-accuracy-S.png",
        include_bytes!("../../docs/bench/speed-accuracy-S.png"),
    ),
    ("lambda.png", include_bytes!("../../docs/bench/lambda.png")),
];

/// Paths served without the token: the page and its static files.
pub fn is_static(path: &str) -> bool {
    matches!(
        path,
        "/" | "/app.js" | "/style.css" | "/api" | "/api.js" | "/openapi.json"
    ) || path.starts_with("/bench/")
}

/// `GET /`: the page.
pub async fn index() -> Response {
    ([(header::CONTENT_TYPE, "text/html; charset=utf-8")], INDEX).into_response()
}

/// `GET /app.js`.
pub async fn app() -> Response {
    (
        [(header::CONTENT_TYPE, "text/javascript; charset=utf-8")],
        APP,
    )
        .into_response()
}

/// `GET /style.css`.
pub async fn style() -> Response {
    ([(header::CONTENT_TYPE, "text/css; charset=utf-8")], STYLE).into_response()
}

/// `GET /api`: the interactive API reference (renders `/openapi.json`).
pub async fn api() -> Response {
    ([(header::CONTENT_TYPE, "text/html; charset=utf-8")], API).into_response()
}

/// `GET /api.js`.
pub async fn api_js() -> Response {
    (
        [(header::CONTENT_TYPE, "text/javascript; charset=utf-8")],
        API_JS,
    )
        .into_response()
}

/// `GET /bench/{name}`: a committed bench chart.
pub async fn chart(Path(name): Path<String>) -> Result<Response, ApiError> {
    let (_, bytes) = CHARTS.iter().find(|(n, _)| *n == name).ok_or_else(|| {
        let names: Vec<&str> = CHARTS.iter().map(|(n, _)| *n).collect();
        ApiError::not_found(format!(
            "no bench chart {name:?}; there are {}",
            names.join(", ")
        ))
    })?;
    Ok(([(header::CONTENT_TYPE, "image/png")], *bytes).into_response())
}
