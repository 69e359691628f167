//! The HTTP server loop: like `axum::serve`, plus what a daemon that runs for
//! weeks needs against slow or greedy clients: a cap on open connections
//! and a smaller one per client address (more are closed at once, so one
//! client holding idle sockets cannot lock the others out), a deadline for
//! each request's headers (which also closes idle keep-alive connections;
//! shorter once three quarters of the connections are taken), and a
//! graceful shutdown that waits a bounded time for requests in flight.
//!
//! [`run`] puts a daemon behind it: the router, the limits of its `[http]`
//! configuration, and the camera stopped once serving ends. It lives here,
//! not in the daemon, so the daemon knows nothing of HTTP.

use std::collections::HashMap;
use std::future::Future;
use std::net::IpAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use axum::Router;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use tokio::net::TcpListener;
use tokio::sync::Semaphore;

use crate::daemon::runtime::config::HttpConfig;
use crate::daemon::Daemon;

/// Connection limits of [`serve`].
#[derive(Debug, Clone, Copy)]
pub struct Limits {
    /// Connections served at once.
    pub max_connections: usize,
    /// Connections served at once from one client address.
    pub per_peer: usize,
    /// Time to send a request's headers, or to start the next request on a
    /// kept-alive connection.
    pub header_timeout: Duration,
}

impl Limits {
    /// The limits an `[http]` configuration sets (a per-client cap above the
    /// total cap is the total cap).
    pub fn of(http: &HttpConfig) -> Self {
        Self {
            max_connections: http.max_connections,
            per_peer: http.max_connections_per_peer.min(http.max_connections),
            header_timeout: Duration::from_secs_f64(http.header_timeout_s),
        }
    }
}

/// Connections closed at once because the cap was reached (for `/metrics`).
pub(crate) static CONNECTIONS_REFUSED: AtomicU64 = AtomicU64::new(0);
/// Connections open now.
pub(crate) static CONNECTIONS_OPEN: AtomicU64 = AtomicU64::new(0);

/// How long shutdown waits for requests in flight (an SSE stream never ends).
const DRAIN: Duration = Duration::from_secs(5);

/// Header deadline of a connection accepted when three quarters of the
/// connections are taken: an idle keep-alive connection then gives its slot
/// back within a second, not after the full deadline.
const PRESSED_HEADER_TIMEOUT: Duration = Duration::from_secs(1);

/// Open connections per client address; a connection's [`PeerSlot`] gives
/// its count back when it ends.
#[derive(Clone, Default)]
struct Peers(Arc<Mutex<HashMap<IpAddr, usize>>>);

/// One connection's share of its peer's count.
struct PeerSlot {
    peers: Peers,
    ip: IpAddr,
}

impl Peers {
    /// A slot for `ip`, unless it already has `cap` connections open.
    fn take(&self, ip: IpAddr, cap: usize) -> Option<PeerSlot> {
        let mut map = self.0.lock().ok()?;
        let n = map.entry(ip).or_insert(0);
        if *n >= cap {
            return None;
        }
        *n += 1;
        Some(PeerSlot {
            peers: self.clone(),
            ip,
        })
    }
}

impl Drop for PeerSlot {
    fn drop(&mut self) {
        if let Ok(mut map) = self.peers.0.lock() {
            if let Some(n) = map.get_mut(&self.ip) {
                *n = n.saturating_sub(1);
                if *n == 0 {
                    map.remove(&self.ip);
                }
            }
        }
    }
}

/// How long a stopping daemon waits for its running jobs to stop (they are
/// stopped at once; a frame in flight or a solver between checks may hold
/// them a few seconds), within systemd's default 90 s stop timeout.
pub(crate) const JOB_DRAIN: Duration = Duration::from_secs(20);

/// Serves the API of `daemon` on `listener` until `shutdown` completes, then
/// drains the daemon (running jobs end `interrupted`, workers joined, camera
/// stopped): the library's entry point (`polnlos serve` wraps it with
/// logging, signals and systemd notification).
pub async fn run(
    listener: TcpListener,
    daemon: Arc<Daemon>,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    let limits = Limits::of(&daemon.config().http);
    let app = super::router(daemon.clone());
    let closing = daemon.clone();
    let shutdown = async move {
        shutdown.await;
        closing.close_streams();
    };
    let result = serve(listener, app, limits, shutdown).await;
    daemon.drain(JOB_DRAIN).await;
    result
}

/// Serves `app` on `listener` until `shutdown` completes.
pub async fn serve(
    listener: TcpListener,
    app: Router,
    limits: Limits,
    shutdown: impl Future<Output = ()>,
) -> std::io::Result<()> {
    let slots = Arc::new(Semaphore::new(limits.max_connections));
    let peers = Peers::default();
    let graceful = hyper_util::server::graceful::GracefulShutdown::new();
    let mut shutdown = std::pin::pin!(shutdown);
    loop {
        let accepted = tokio::select! {
            a = listener.accept() => a,
            () = &mut shutdown => break,
        };
        let (stream, peer) = match accepted {
            Ok(a) => a,
            Err(e) => {
                // Out of file descriptors and the like: back off, keep serving.
                tracing::warn!("accept failed: {e}");
                tokio::time::sleep(Duration::from_millis(50)).await;
                continue;
            }
        };
        let Some(peer_slot) = peers.take(peer.ip(), limits.per_peer) else {
            CONNECTIONS_REFUSED.fetch_add(1, Ordering::Relaxed);
            drop(stream);
            continue;
        };
        let Ok(slot) = slots.clone().try_acquire_owned() else {
            CONNECTIONS_REFUSED.fetch_add(1, Ordering::Relaxed);
            drop(stream);
            continue;
        };
        let pressed = slots.available_permits() < limits.max_connections / 4;
        let header_timeout = if pressed {
            limits.header_timeout.min(PRESSED_HEADER_TIMEOUT)
        } else {
            limits.header_timeout
        };
        let service = TowerToHyperService::new(app.clone());
        let conn = hyper::server::conn::http1::Builder::new()
            .timer(TokioTimer::new())
            .header_read_timeout(header_timeout)
            .serve_connection(TokioIo::new(stream), service);
        let conn = graceful.watch(conn);
        CONNECTIONS_OPEN.fetch_add(1, Ordering::Relaxed);
        tokio::spawn(async move {
            if let Err(e) = conn.await {
                tracing::debug!("connection ended: {e}");
            }
            CONNECTIONS_OPEN.fetch_sub(1, Ordering::Relaxed);
            drop(slot);
            drop(peer_slot);
        });
    }
    drop(listener);
    if tokio::time::timeout(DRAIN, graceful.shutdown())
        .await
        .is_err()
    {
        tracing::info!("closed connections still busy after {DRAIN:?}");
    }
    Ok(())
}
