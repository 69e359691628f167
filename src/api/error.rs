//! JSON errors: `{ "error": code, "detail": text }` with the right status.

use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;

/// An error answer.
#[derive(Debug)]
pub struct ApiError {
    status: StatusCode,
    code: &'static str,
    detail: String,
    retry_after: Option<u64>,
}

impl ApiError {
    /// Any status, code and detail.
    pub fn new(status: StatusCode, code: &'static str, detail: impl Into<String>) -> Self {
        Self {
            status,
            code,
            detail: detail.into(),
            retry_after: None,
        }
    }
    /// 404.
    pub fn not_found(detail: impl Into<String>) -> Self {
        Self::new(StatusCode::NOT_FOUND, "not_found", detail)
    }
    /// 422: well-formed but unacceptable.
    pub fn invalid(detail: impl Into<String>) -> Self {
        Self::new(StatusCode::UNPROCESSABLE_ENTITY, "invalid_request", detail)
    }
    /// 401 without a token: what needs one and where the token is set.
    pub fn token_missing(mutating: bool) -> Self {
        let what = if mutating {
            "this request changes state"
        } else {
            "this daemon answers reads only with its token ([http] public_reads = false), and this request"
        };
        Self::new(
            StatusCode::UNAUTHORIZED,
            "token_missing",
            format!("{what} needs 'Authorization: Bearer <token>' (the token or token_file in the daemon's config)"),
        )
    }
    /// 401 with a token that is not the daemon's.
    pub fn token_wrong() -> Self {
        Self::new(
            StatusCode::UNAUTHORIZED,
            "token_wrong",
            "the bearer token given is not this daemon's: check it against the token or token_file in the daemon's config",
        )
    }
    /// 429 with Retry-After.
    pub fn queue_full(which: &str, retry_after: u64) -> Self {
        Self {
            retry_after: Some(retry_after),
            ..Self::new(
                StatusCode::TOO_MANY_REQUESTS,
                "queue_full",
                format!("the {which} queue is full; retry after {retry_after} s"),
            )
        }
    }
    /// 503: the camera is not available.
    pub fn unavailable(detail: impl Into<String>) -> Self {
        Self::new(
            StatusCode::SERVICE_UNAVAILABLE,
            "camera_unavailable",
            detail,
        )
    }
    /// 500 for a store or file problem; the detail says what (e.g. a full disk).
    pub fn internal(detail: impl Into<String>) -> Self {
        Self::new(StatusCode::INTERNAL_SERVER_ERROR, "internal", detail)
    }
    /// 409: the request conflicts with what the daemon is doing.
    pub fn busy(detail: impl Into<String>) -> Self {
        Self::new(StatusCode::CONFLICT, "busy", detail)
    }
    /// 400: a query string or path that cannot be read.
    pub fn bad_request(detail: impl Into<String>) -> Self {
        Self::new(StatusCode::BAD_REQUEST, "bad_request", detail)
    }
    /// 403: a request addressed to a host name or from an origin not allowed.
    pub fn forbidden(detail: impl Into<String>) -> Self {
        Self::new(StatusCode::FORBIDDEN, "forbidden", detail)
    }
}

impl From<crate::store::StoreError> for ApiError {
    fn from(e: crate::store::StoreError) -> Self {
        match e {
            crate::store::StoreError::NotFound { .. } => Self::not_found(e.to_string()),
            crate::store::StoreError::InUse { .. } => {
                Self::new(StatusCode::CONFLICT, "in_use", e.to_string())
            }
            // The full text names files on the server: the log has it, the client a summary.
            e => {
                tracing::error!("catalogue: {e}");
                Self::internal(
                    "the catalogue could not be read or written (a full or read-only disk?); the daemon's log has the details",
                )
            }
        }
    }
}

impl From<crate::daemon::RequestError> for ApiError {
    fn from(e: crate::daemon::RequestError) -> Self {
        match e {
            crate::daemon::RequestError::NotFound(m) => Self::not_found(m),
            crate::daemon::RequestError::Invalid(m) => Self::invalid(m),
            crate::daemon::RequestError::Unavailable(m) => Self::unavailable(m),
            crate::daemon::RequestError::Store(m) => Self::internal(m),
            crate::daemon::RequestError::Busy(m) => Self::busy(m),
        }
    }
}

impl From<crate::daemon::SubmitError> for ApiError {
    fn from(e: crate::daemon::SubmitError) -> Self {
        use crate::daemon::SubmitError;
        match e {
            SubmitError::Disk { .. } => Self::new(
                StatusCode::INSUFFICIENT_STORAGE,
                "insufficient_storage",
                e.to_string(),
            ),
            SubmitError::QueueFull { queue, retry_after } => Self::queue_full(queue, retry_after),
            SubmitError::Request(r) => r.into(),
            SubmitError::Internal(m) => Self::internal(m),
        }
    }
}

impl From<crate::daemon::CancelError> for ApiError {
    fn from(e: crate::daemon::CancelError) -> Self {
        use crate::daemon::CancelError;
        match e {
            CancelError::NotFound { .. } => Self::not_found(e.to_string()),
            CancelError::Ended { .. } => Self::new(StatusCode::CONFLICT, "ended", e.to_string()),
            CancelError::Store(m) => Self::internal(m),
        }
    }
}

impl From<crate::daemon::PlanError> for ApiError {
    fn from(e: crate::daemon::PlanError) -> Self {
        use crate::daemon::PlanError;
        match e {
            PlanError::NotFound(_) => Self::not_found(e.to_string()),
            PlanError::NotWaiting { .. } => {
                Self::new(StatusCode::CONFLICT, "not_waiting", e.to_string())
            }
            PlanError::Ended { .. } => Self::new(StatusCode::CONFLICT, "ended", e.to_string()),
            PlanError::Submit(s) => s.into(),
        }
    }
}

impl From<crate::daemon::SettingsError> for ApiError {
    fn from(e: crate::daemon::SettingsError) -> Self {
        use crate::camera::CameraError;
        use crate::daemon::SettingsError;
        match e {
            SettingsError::Busy => Self::busy(e.to_string()),
            SettingsError::Geometry(_)
            | SettingsError::Camera(
                CameraError::OutOfRange { .. }
                | CameraError::Feature { .. }
                | CameraError::Geometry(_),
            ) => Self::invalid(e.to_string()),
            SettingsError::Camera(_) => Self::unavailable(e.to_string()),
        }
    }
}

impl From<axum::extract::rejection::QueryRejection> for ApiError {
    fn from(r: axum::extract::rejection::QueryRejection) -> Self {
        Self::bad_request(format!(
            "query string: {}",
            r.body_text()
                .trim_start_matches("Failed to deserialize query string: ")
        ))
    }
}

impl From<axum::extract::rejection::PathRejection> for ApiError {
    fn from(r: axum::extract::rejection::PathRejection) -> Self {
        Self::bad_request(format!("path: {}", r.body_text()))
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let mut res = (
            self.status,
            Json(serde_json::json!({ "error": self.code, "detail": self.detail })),
        )
            .into_response();
        if let Some(s) = self.retry_after {
            if let Ok(v) = HeaderValue::from_str(&s.to_string()) {
                res.headers_mut().insert(header::RETRY_AFTER, v);
            }
        }
        res
    }
}
