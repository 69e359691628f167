//! The thread that owns the camera. Requests arrive on a channel; replies go
//! back on one-shot channels. When the camera is lost the thread drops it and
//! reopens it with exponential backoff (0.25 s doubling to 10 s), or at once
//! when told to rescan (USB hot-plug).

use std::sync::mpsc::{self, RecvTimeoutError};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::sync::oneshot;

use super::device::{CameraDevice, CameraError, CameraInfo, Counters, RawFrame};
use super::settings::CameraSettings;

/// Opens the camera (again): the worker calls it at start and after a loss.
pub type Opener = Box<dyn Fn() -> Result<Box<dyn CameraDevice>, CameraError> + Send>;

enum Request {
    Describe(oneshot::Sender<Result<CameraInfo, CameraError>>),
    Configure(CameraSettings, oneshot::Sender<Result<(), CameraError>>),
    Acquire {
        settings: CameraSettings,
        n: usize,
        sink: mpsc::SyncSender<RawFrame>,
        reply: oneshot::Sender<Result<(), CameraError>>,
    },
    Rescan,
    Shutdown,
}

/// Connection state and counters, readable without asking the camera thread.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct CameraStatus {
    /// Whether a camera is open.
    pub connected: bool,
    /// Why it is not, when it is not.
    pub last_error: Option<String>,
    /// Counters accumulated over every connection.
    pub counters: Counters,
    /// Reconnection attempts that failed.
    pub reconnect_failures: u64,
    /// The camera's description, with its settings as read back after the
    /// last (re)connection, configuration or acquisition.
    pub info: Option<CameraInfo>,
}

/// A cheap, cloneable handle to the camera thread.
#[derive(Clone)]
pub struct CameraHandle {
    tx: mpsc::Sender<Request>,
    status: Arc<Mutex<CameraStatus>>,
}

const BACKOFF_MIN: Duration = Duration::from_millis(250);
const BACKOFF_MAX: Duration = Duration::from_secs(10);

impl CameraHandle {
    /// Starts the camera thread; it opens the camera with `opener` right away.
    pub fn spawn(opener: Opener) -> Self {
        let (tx, rx) = mpsc::channel();
        let status = Arc::new(Mutex::new(CameraStatus::default()));
        let st = status.clone();
        let spawned = std::thread::Builder::new()
            .name("camera".into())
            .spawn(move || run(opener, rx, st));
        if let Err(e) = spawned {
            tracing::error!("cannot start the camera thread: {e}");
        }
        Self { tx, status }
    }

    fn gone() -> CameraError {
        CameraError::Disconnected("the camera thread has stopped".into())
    }

    /// Snapshot of the connection state and counters.
    pub fn status(&self) -> CameraStatus {
        self.status.lock().map(|s| s.clone()).unwrap_or_default()
    }

    /// Identity, ranges and settings of the open camera, read from it now
    /// (waits while an acquisition runs).
    pub async fn describe(&self) -> Result<CameraInfo, CameraError> {
        let (reply, rx) = oneshot::channel();
        self.tx
            .send(Request::Describe(reply))
            .map_err(|_| Self::gone())?;
        rx.await.map_err(|_| Self::gone())?
    }

    /// Applies settings now (and keeps them for later captures).
    pub async fn configure(&self, settings: CameraSettings) -> Result<(), CameraError> {
        let (reply, rx) = oneshot::channel();
        self.tx
            .send(Request::Configure(settings, reply))
            .map_err(|_| Self::gone())?;
        rx.await.map_err(|_| Self::gone())?
    }

    /// Configures and acquires `n` frames, sending each into `sink` as it
    /// arrives. The sink is bounded: a slow receiver holds the camera thread
    /// back (the camera's own buffers absorb it) instead of piling frames up
    /// in memory; a dropped receiver stops the acquisition.
    pub async fn acquire(
        &self,
        settings: CameraSettings,
        n: usize,
        sink: mpsc::SyncSender<RawFrame>,
    ) -> Result<(), CameraError> {
        let (reply, rx) = oneshot::channel();
        self.tx
            .send(Request::Acquire {
                settings,
                n,
                sink,
                reply,
            })
            .map_err(|_| Self::gone())?;
        rx.await.map_err(|_| Self::gone())?
    }

    /// Acquires `n` frames and returns them all (holds every frame in
    /// memory: for tests and a few frames, not for captures).
    pub async fn collect(
        &self,
        settings: CameraSettings,
        n: usize,
    ) -> Result<Vec<RawFrame>, CameraError> {
        let (tx, rx) = mpsc::sync_channel(n.max(1));
        self.acquire(settings, n, tx).await?;
        Ok(rx.try_iter().collect())
    }

    /// Asks the thread to try reopening a lost camera now.
    pub fn rescan(&self) {
        let _ = self.tx.send(Request::Rescan);
    }

    /// Stops the camera thread (closing the camera).
    pub fn shutdown(&self) {
        let _ = self.tx.send(Request::Shutdown);
    }
}

fn run(opener: Opener, rx: mpsc::Receiver<Request>, status: Arc<Mutex<CameraStatus>>) {
    let mut camera: Option<Box<dyn CameraDevice>> = None;
    let mut base = Counters::default();
    let mut backoff = Duration::ZERO;
    let update = |f: &mut dyn FnMut(&mut CameraStatus)| {
        if let Ok(mut s) = status.lock() {
            f(&mut s);
        }
    };
    loop {
        if camera.is_none() {
            match opener() {
                Ok(mut c) => {
                    let info = c.describe().ok();
                    tracing::info!(camera = ?info.as_ref().map(|i| &i.id), "camera connected");
                    update(&mut |s| {
                        s.connected = true;
                        s.last_error = None;
                        s.counters.connects += 1;
                        s.info = info.clone();
                    });
                    camera = Some(c);
                    backoff = Duration::ZERO;
                }
                Err(e) => {
                    backoff = (backoff * 2).clamp(BACKOFF_MIN, BACKOFF_MAX);
                    tracing::warn!("camera not available, retrying in {:?}: {e}", backoff);
                    update(&mut |s| {
                        s.connected = false;
                        s.last_error = Some(e.to_string());
                        s.reconnect_failures += 1;
                    });
                }
            }
        }
        let req = if camera.is_some() {
            rx.recv().map_err(|_| RecvTimeoutError::Disconnected)
        } else {
            rx.recv_timeout(backoff)
        };
        let req = match req {
            Ok(r) => r,
            Err(RecvTimeoutError::Timeout) => continue,
            Err(RecvTimeoutError::Disconnected) => return,
        };
        let not_connected = || {
            CameraError::Disconnected(
                status
                    .lock()
                    .ok()
                    .and_then(|s| s.last_error.clone())
                    .unwrap_or_else(|| "not opened yet".into()),
            )
        };
        let mut lost = None;
        match req {
            Request::Shutdown => return,
            Request::Rescan => backoff = Duration::ZERO,
            Request::Describe(reply) => {
                let r = camera
                    .as_mut()
                    .map_or_else(|| Err(not_connected()), |c| c.describe());
                if let Ok(info) = &r {
                    update(&mut |s| s.info = Some(info.clone()));
                }
                let _ = reply.send(r);
            }
            Request::Configure(settings, reply) => {
                let r = camera
                    .as_mut()
                    .map_or_else(|| Err(not_connected()), |c| c.configure(&settings));
                if let Some(info) = camera.as_mut().and_then(|c| c.describe().ok()) {
                    update(&mut |s| s.info = Some(info.clone()));
                }
                let _ = reply.send(r);
            }
            Request::Acquire {
                settings,
                n,
                sink,
                reply,
            } => {
                let r = match camera.as_mut() {
                    None => Err(not_connected()),
                    Some(c) => c.configure(&settings).and_then(|()| {
                        if let Ok(info) = c.describe() {
                            update(&mut |s| s.info = Some(info.clone()));
                        }
                        c.acquire(n, &mut |f| {
                            sink.send(f)
                                .map_err(|_| "the frame writer stopped".to_string())
                        })
                    }),
                };
                if let Some(c) = camera.as_ref() {
                    let k = c.counters();
                    update(&mut |s| {
                        s.counters = Counters {
                            connects: s.counters.connects,
                            ..add(base, k)
                        }
                    });
                }
                if let Err(e) = &r {
                    if e.is_connection_loss() {
                        lost = Some(e.to_string());
                    }
                }
                let _ = reply.send(r);
            }
        }
        if let Some(why) = lost {
            if let Some(c) = camera.take() {
                base = add(base, c.counters());
            }
            tracing::warn!("camera lost: {why}");
            update(&mut |s| {
                s.connected = false;
                s.last_error = Some(why.clone());
            });
            backoff = Duration::ZERO;
        }
    }
}

fn add(a: Counters, b: Counters) -> Counters {
    Counters {
        completed: a.completed + b.completed,
        failed: a.failed + b.failed,
        timeouts: a.timeouts + b.timeouts,
        underruns: a.underruns + b.underruns,
        missing_packets: a.missing_packets + b.missing_packets,
        resent_packets: a.resent_packets + b.resent_packets,
        connects: a.connects,
    }
}
