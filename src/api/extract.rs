//! `Query` and `Path` extractors whose rejections are JSON [`ApiError`]s
//! (axum's own answer in plain text).

use axum::extract::{FromRequestParts, Path, Query};
use axum::http::request::Parts;
use serde::de::DeserializeOwned;

use super::ApiError;
use crate::daemon::runtime::scene_registry::MAX_SCENE_BYTES;

/// A query string, or a 400 JSON error naming the bad parameter.
pub struct ApiQuery<T>(pub T);

impl<S: Send + Sync, T: DeserializeOwned> FromRequestParts<S> for ApiQuery<T> {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, state: &S) -> Result<Self, ApiError> {
        let Query(v) = Query::<T>::from_request_parts(parts, state).await?;
        Ok(ApiQuery(v))
    }
}

/// A path parameter, or a 400 JSON error (e.g. bytes that are not UTF-8).
pub struct ApiPath<T>(pub T);

impl<S: Send + Sync, T: DeserializeOwned + Send> FromRequestParts<S> for ApiPath<T> {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, state: &S) -> Result<Self, ApiError> {
        let Path(v) = Path::<T>::from_request_parts(parts, state).await?;
        Ok(ApiPath(v))
    }
}

/// A request's media type, lower case, without its parameters (`; charset=`).
fn media_type(req: &axum::extract::Request) -> Option<String> {
    let v = req
        .headers()
        .get(axum::http::header::CONTENT_TYPE)?
        .to_str()
        .ok()?;
    Some(
        v.split(';')
            .next()
            .unwrap_or("")
            .trim()
            .to_ascii_lowercase(),
    )
}

/// A JSON body: 415 without a JSON content type, 413 over the size limit,
/// 400 when the bytes are not JSON at all, 422 when they are JSON of the
/// wrong shape (a missing field, a string for a number, an array for an object).
pub struct ApiJson<T>(pub T);

impl<S: Send + Sync, T: DeserializeOwned> axum::extract::FromRequest<S> for ApiJson<T> {
    type Rejection = ApiError;

    async fn from_request(req: axum::extract::Request, state: &S) -> Result<Self, ApiError> {
        use axum::http::StatusCode;
        let json_type =
            media_type(&req).is_some_and(|m| m == "application/json" || m.ends_with("+json"));
        if !json_type {
            return Err(ApiError::new(
                StatusCode::UNSUPPORTED_MEDIA_TYPE,
                "unsupported_media_type",
                "send the body as JSON with 'Content-Type: application/json'",
            ));
        }
        let bytes = axum::body::Bytes::from_request(req, state)
            .await
            .map_err(|r| match r.status() {
                StatusCode::PAYLOAD_TOO_LARGE => ApiError::new(
                    StatusCode::PAYLOAD_TOO_LARGE,
                    "body_too_large",
                    "the request body is over the limit ([queue] max_body_bytes)",
                ),
                s => ApiError::new(s, "bad_request", r.body_text()),
            })?;
        let value: serde_json::Value = serde_json::from_slice(&bytes).map_err(|e| {
            ApiError::new(
                StatusCode::BAD_REQUEST,
                "malformed_json",
                format!("the body is not JSON: {e}"),
            )
        })?;
        serde_path_to_error::deserialize(value)
            .map(ApiJson)
            .map_err(|e| match e.path().to_string().as_str() {
                "." => ApiError::invalid(e.inner().to_string()),
                path => ApiError::invalid(format!("{path}: {}", e.inner())),
            })
    }
}

/// A TOML body (a scene file): 415 without `application/toml`, 413 over
/// [`MAX_SCENE_BYTES`], 422 when the bytes are not UTF-8 text.
pub struct ApiToml(pub String);

impl<S: Send + Sync> axum::extract::FromRequest<S> for ApiToml {
    type Rejection = ApiError;

    async fn from_request(req: axum::extract::Request, state: &S) -> Result<Self, ApiError> {
        use axum::http::StatusCode;
        let toml_type = media_type(&req).is_some_and(|m| m == "application/toml");
        if !toml_type {
            return Err(ApiError::new(
                StatusCode::UNSUPPORTED_MEDIA_TYPE,
                "unsupported_media_type",
                "send the scene file as the body with 'Content-Type: application/toml'",
            ));
        }
        // The scene routes' body limit is MAX_SCENE_BYTES (api::all_routes).
        let bytes = axum::body::Bytes::from_request(req, state)
            .await
            .map_err(|r| match r.status() {
                StatusCode::PAYLOAD_TOO_LARGE => ApiError::new(
                    StatusCode::PAYLOAD_TOO_LARGE,
                    "body_too_large",
                    format!("a scene file is at most {MAX_SCENE_BYTES} bytes"),
                ),
                s => ApiError::new(s, "bad_request", r.body_text()),
            })?;
        String::from_utf8(bytes.to_vec())
            .map(ApiToml)
            .map_err(|e| ApiError::invalid(format!("the scene file is not UTF-8 text: {e}")))
    }
}
