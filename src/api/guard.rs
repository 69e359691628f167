//! What every request passes before a handler sees it: size limits on the
//! target and headers (JSON 414/431 instead of hyper's empty answers), the
//! `Host` and `Origin` checks against DNS rebinding, and the bearer token.

use std::sync::Arc;

use axum::extract::{Request, State};
use axum::http::{header, HeaderMap, Method, StatusCode};
use axum::middleware::Next;
use axum::response::Response;
use sha2::{Digest, Sha256};

use super::ApiError;
use crate::daemon::Daemon;

/// Longest request target accepted, bytes.
pub const MAX_URI_BYTES: usize = 8 * 1024;
/// Most header bytes (names and values) accepted.
pub const MAX_HEADER_BYTES: usize = 16 * 1024;
/// Most header lines accepted.
pub const MAX_HEADERS: usize = 64;

/// What the guard checks against, fixed when the router is built.
#[derive(Clone)]
pub struct Guard {
    daemon: Arc<Daemon>,
    /// Host names the daemon answers to (see [`allowed_hosts`]).
    hosts: Arc<[String]>,
}

impl Guard {
    /// The guard of a daemon: its token, its bound address and allowed names.
    pub fn new(daemon: Arc<Daemon>) -> Self {
        let hosts = allowed_hosts(&daemon).into();
        Self { daemon, hosts }
    }
}

/// Who may send this request, and whether it is small enough to read.
pub async fn guard(State(g): State<Guard>, req: Request, next: Next) -> Result<Response, ApiError> {
    let d = &g.daemon;
    let uri = req.uri();
    let uri_len = uri.path_and_query().map_or(0, |p| p.as_str().len())
        + uri.authority().map_or(0, |a| a.as_str().len());
    if uri_len > MAX_URI_BYTES {
        return Err(ApiError::new(
            StatusCode::URI_TOO_LONG,
            "uri_too_long",
            format!("the request target is {uri_len} bytes; at most {MAX_URI_BYTES}"),
        ));
    }
    let headers = req.headers();
    let header_bytes: usize = headers
        .iter()
        .map(|(k, v)| k.as_str().len() + v.len())
        .sum();
    if header_bytes > MAX_HEADER_BYTES || headers.len() > MAX_HEADERS {
        return Err(ApiError::new(
            StatusCode::REQUEST_HEADER_FIELDS_TOO_LARGE,
            "headers_too_large",
            format!(
                "{} header lines, {header_bytes} bytes; at most {MAX_HEADERS} lines and {MAX_HEADER_BYTES} bytes",
                headers.len()
            ),
        ));
    }
    check_host(headers, &g.hosts)?;
    let mutating = !matches!(*req.method(), Method::GET | Method::HEAD | Method::OPTIONS);
    if mutating {
        check_origin(headers, &g.hosts, d.config().bind.port())?;
    }
    let path = req.uri().path();
    let public = path == "/health"
        || (!mutating && (d.config().http.public_reads || super::web::is_static(path)));
    if !d.token().is_empty() && !public {
        match token_given(headers, d.token()) {
            Token::Right => {}
            Token::Missing => return Err(ApiError::token_missing(mutating)),
            Token::Wrong => return Err(ApiError::token_wrong()),
        }
    }
    Ok(next.run(req).await)
}

/// Host names the daemon answers to: the bound address, the loopback names,
/// and `[http] allowed_hosts`.
fn allowed_hosts(d: &Daemon) -> Vec<String> {
    let mut names: Vec<String> = ["localhost", "127.0.0.1", "::1"]
        .into_iter()
        .map(String::from)
        .collect();
    names.push(d.config().bind.ip().to_string());
    names.extend(
        d.config()
            .http
            .allowed_hosts
            .iter()
            .map(|h| h.to_ascii_lowercase()),
    );
    names
}

/// The host part of a `Host` value or an origin's authority, lower case,
/// without port or IPv6 brackets.
fn host_name(authority: &str) -> String {
    let a = authority.trim().to_ascii_lowercase();
    if let Some(rest) = a.strip_prefix('[') {
        return rest.split(']').next().unwrap_or_default().to_string();
    }
    a.rsplit_once(':')
        .filter(|(_, port)| port.chars().all(|c| c.is_ascii_digit()))
        .map_or(a.clone(), |(h, _)| h.to_string())
}

fn check_host(headers: &HeaderMap, allowed: &[String]) -> Result<(), ApiError> {
    // HTTP/1.0 clients may send no Host; a browser always does.
    let Some(host) = headers.get(header::HOST) else {
        return Ok(());
    };
    let name = host.to_str().map(host_name).unwrap_or_default();
    if allowed.contains(&name) {
        return Ok(());
    }
    Err(ApiError::forbidden(format!(
        "this daemon does not answer to host {name:?}; use its address, or add the name to [http] allowed_hosts"
    )))
}

/// The port of a `Host` value or an origin's authority, when it names one.
fn port_of(authority: &str) -> Option<u16> {
    let a = authority.trim();
    let tail = match a.strip_prefix('[') {
        Some(rest) => rest.split_once(']').map(|(_, t)| t)?,
        None => a,
    };
    let (_, port) = tail.rsplit_once(':')?;
    port.parse().ok()
}

/// A state-changing request must come from the daemon's own origin: an
/// allowed host name *and* the port the request was sent to (the `Host`
/// header's, else the bound one). Why the port: another web server on the
/// same machine (`http://localhost:9999`) is another origin, and a page it
/// serves must not drive the bench.
fn check_origin(headers: &HeaderMap, allowed: &[String], bound: u16) -> Result<(), ApiError> {
    let Some(origin) = headers.get(header::ORIGIN) else {
        return Ok(());
    };
    let text = origin.to_str().unwrap_or_default();
    let (authority, default_port) = match text.strip_prefix("http://") {
        Some(a) => (a, 80),
        None => (text.strip_prefix("https://").unwrap_or(""), 443),
    };
    let name = host_name(authority);
    let port = port_of(authority).unwrap_or(default_port);
    let served = headers
        .get(header::HOST)
        .and_then(|h| h.to_str().ok())
        .and_then(port_of)
        .unwrap_or(bound);
    if !name.is_empty() && allowed.contains(&name) && port == served {
        return Ok(());
    }
    Err(ApiError::forbidden(format!(
        "requests that change state are not accepted from origin {text:?}: only from this daemon's own pages (port {served}); add its host to [http] allowed_hosts if it is yours"
    )))
}

/// Whether `Authorization: Bearer <token>` carries the token. The scheme is
/// case-insensitive (RFC 7235); the compare is on SHA-256 digests, so its
/// time depends on neither the token's length nor where they differ.
/// What a request's `Authorization` header holds against the daemon's token.
#[derive(Debug, PartialEq)]
enum Token {
    /// No bearer token at all (no header, or another scheme).
    Missing,
    /// A bearer token that is not the daemon's.
    Wrong,
    /// The daemon's token.
    Right,
}

fn token_given(headers: &HeaderMap, token: &str) -> Token {
    let Some(value) = headers.get(header::AUTHORIZATION) else {
        return Token::Missing;
    };
    let Some((scheme, given)) = value.to_str().ok().and_then(|v| v.trim().split_once(' ')) else {
        return Token::Wrong;
    };
    if !scheme.eq_ignore_ascii_case("bearer") {
        return Token::Missing;
    }
    let (a, b) = (
        Sha256::digest(given.trim().as_bytes()),
        Sha256::digest(token.as_bytes()),
    );
    let differ = a
        .iter()
        .zip(b.iter())
        .fold(0u8, |acc, (x, y)| acc | (x ^ y));
    if differ == 0 {
        Token::Right
    } else {
        Token::Wrong
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn with(name: header::HeaderName, value: &str) -> HeaderMap {
        let mut h = HeaderMap::new();
        h.insert(name, value.parse().unwrap());
        h
    }

    #[test]
    fn host_names_drop_ports_and_brackets() {
        assert_eq!(host_name("127.0.0.1:8470"), "127.0.0.1");
        assert_eq!(host_name("LocalHost"), "localhost");
        assert_eq!(host_name("[::1]:8470"), "::1");
        assert_eq!(host_name("evil.example:80"), "evil.example");
    }

    #[test]
    fn rebinding_hosts_and_foreign_origins_are_refused() {
        let allowed: Vec<String> = vec!["localhost".into(), "127.0.0.1".into(), "::1".into()];
        assert!(check_host(&with(header::HOST, "127.0.0.1:8470"), &allowed).is_ok());
        assert!(check_host(&with(header::HOST, "[::1]:1"), &allowed).is_ok());
        assert!(check_host(&HeaderMap::new(), &allowed).is_ok());
        assert!(check_host(&with(header::HOST, "attacker.example:8470"), &allowed).is_err());
        assert!(check_origin(
            &with(header::ORIGIN, "http://localhost:8470"),
            &allowed,
            8470
        )
        .is_ok());
        assert!(check_origin(
            &with(header::ORIGIN, "http://attacker.example"),
            &allowed,
            8470
        )
        .is_err());
        assert!(check_origin(&with(header::ORIGIN, "null"), &allowed, 8470).is_err());
        // Another port on the same host is another origin.
        assert!(check_origin(
            &with(header::ORIGIN, "http://localhost:9999"),
            &allowed,
            8470
        )
        .is_err());
        assert!(check_origin(&with(header::ORIGIN, "http://localhost"), &allowed, 8470).is_err());
        assert!(check_origin(&with(header::ORIGIN, "http://[::1]:8470"), &allowed, 8470).is_ok());
        // The port the request was sent to (Host) is the daemon's own.
        let mut h = with(header::ORIGIN, "http://127.0.0.1:18470");
        h.insert(header::HOST, "127.0.0.1:18470".parse().unwrap());
        assert!(check_origin(&h, &allowed, 8470).is_ok());
        assert_eq!(port_of("[::1]:8470"), Some(8470));
        assert_eq!(port_of("localhost"), None);
    }

    #[test]
    fn bearer_is_case_insensitive_and_exact_and_a_wrong_one_is_not_a_missing_one() {
        let t = "s3cret";
        let given = |v: &str| token_given(&with(header::AUTHORIZATION, v), t);
        assert_eq!(given("Bearer s3cret"), Token::Right);
        assert_eq!(given("bearer s3cret"), Token::Right);
        assert_eq!(given("BEARER  s3cret "), Token::Right);
        assert_eq!(given("Bearer s3cre"), Token::Wrong);
        assert_eq!(given("Bearer s3cretx"), Token::Wrong);
        assert_eq!(given("s3cret"), Token::Wrong);
        assert_eq!(given("Basic s3cret"), Token::Missing);
        assert_eq!(token_given(&HeaderMap::new(), t), Token::Missing);
    }
}
