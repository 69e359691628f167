//! The thread that owns the camera. Requests arrive on a channel; replies go
//! back on one-shot channels. When the camera is lost the thread drops it and
//! reopens it with exponential backoff (0.25 s doubling to 10 s), or at once
//! when told to rescan (USB hot-plug).

use std::sync::mpsc::{self, RecvTimeoutError, SyncSender};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::sync::oneshot;

use super::device::{
    CameraDevice, CameraError, CameraInfo, Counters, FrameCounts, RawFrame, SinkClosed,
};
use super::settings::Acquisition;

/// Opens the camera (again): the worker calls it at start and after a loss.
pub(crate) type Opener = Box<dyn Fn() -> Result<Box<dyn CameraDevice>, CameraError> + Send>;

enum Request {
    Describe(oneshot::Sender<Result<CameraInfo, CameraError>>),
    Configure(Acquisition, oneshot::Sender<Result<(), CameraError>>),
    Acquire {
        settings: Acquisition,
        n: usize,
        sink: mpsc::SyncSender<RawFrame>,
        reply: oneshot::Sender<Result<FrameCounts, CameraError>>,
    },
    Rescan,
    Shutdown,
}

/// Connection state and counters, readable without asking the camera thread.
#[derive(Debug, Clone, Default, serde::Serialize, utoipa::ToSchema)]
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
    pub async fn configure(&self, settings: Acquisition) -> Result<(), CameraError> {
        let (reply, rx) = oneshot::channel();
        self.tx
            .send(Request::Configure(settings, reply))
            .map_err(|_| Self::gone())?;
        rx.await.map_err(|_| Self::gone())?
    }

    /// Configures and acquires `n` frames, sending each into `sink` as it
    /// arrives. The sink is bounded: a slow receiver holds the camera thread
    /// back (the camera's own buffers absorb it) instead of piling frames up
    /// in memory; a dropped receiver stops the acquisition. Returns what
    /// this acquisition received and lost.
    pub async fn acquire(
        &self,
        settings: Acquisition,
        n: usize,
        sink: mpsc::SyncSender<RawFrame>,
    ) -> Result<FrameCounts, CameraError> {
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
        settings: Acquisition,
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
    let mut w = Worker {
        opener,
        status,
        camera: None,
        base: Counters::default(),
        backoff: Duration::ZERO,
    };
    loop {
        if w.camera.is_none() {
            w.open();
        }
        let req = if w.camera.is_some() {
            rx.recv().map_err(|_| RecvTimeoutError::Disconnected)
        } else {
            rx.recv_timeout(w.backoff)
        };
        match req {
            Ok(Request::Shutdown) | Err(RecvTimeoutError::Disconnected) => return,
            Ok(Request::Rescan) => w.backoff = Duration::ZERO,
            Ok(req) => w.handle(req),
            Err(RecvTimeoutError::Timeout) => {}
        }
    }
}

/// The camera thread's state: the open camera (if any), counters of cameras
/// lost before it, and the reconnection backoff.
struct Worker {
    opener: Opener,
    status: Arc<Mutex<CameraStatus>>,
    camera: Option<Box<dyn CameraDevice>>,
    base: Counters,
    backoff: Duration,
}

impl Worker {
    fn update(&self, f: impl FnOnce(&mut CameraStatus)) {
        if let Ok(mut s) = self.status.lock() {
            f(&mut s);
        }
    }

    /// Tries to open the camera; on failure doubles the backoff.
    fn open(&mut self) {
        match (self.opener)() {
            Ok(mut c) => {
                let info = c.describe().ok();
                tracing::info!(camera = ?info.as_ref().map(|i| &i.id), "camera connected");
                self.update(|s| {
                    s.connected = true;
                    s.last_error = None;
                    s.counters.connects += 1;
                    s.info = info;
                });
                self.camera = Some(c);
                self.backoff = Duration::ZERO;
            }
            Err(e) => {
                self.backoff = (self.backoff * 2).clamp(BACKOFF_MIN, BACKOFF_MAX);
                tracing::warn!("camera not available, retrying in {:?}: {e}", self.backoff);
                self.update(|s| {
                    s.connected = false;
                    s.last_error = Some(e.to_string());
                    s.reconnect_failures += 1;
                });
            }
        }
    }

    fn not_connected(&self) -> CameraError {
        let last = self.status.lock().ok().and_then(|s| s.last_error.clone());
        CameraError::Disconnected(last.unwrap_or_else(|| "not opened yet".into()))
    }

    /// Reads the camera's description into the status.
    fn refresh(&mut self) {
        if let Some(info) = self.camera.as_mut().and_then(|c| c.describe().ok()) {
            self.update(|s| s.info = Some(info));
        }
    }

    fn handle(&mut self, req: Request) {
        match req {
            Request::Shutdown | Request::Rescan => {}
            Request::Describe(reply) => {
                let r = match self.camera.as_mut() {
                    Some(c) => c.describe(),
                    None => Err(self.not_connected()),
                };
                if let Ok(info) = &r {
                    let info = info.clone();
                    self.update(|s| s.info = Some(info));
                }
                let _ = reply.send(r);
            }
            Request::Configure(settings, reply) => {
                let r = match self.camera.as_mut() {
                    Some(c) => c.configure(&settings),
                    None => Err(self.not_connected()),
                };
                self.refresh();
                let _ = reply.send(r);
            }
            Request::Acquire {
                settings,
                n,
                sink,
                reply,
            } => {
                let r = self.acquire(&settings, n, &sink);
                if let Err(e) = &r {
                    if e.is_connection_loss() {
                        self.lose(e.to_string());
                    }
                }
                let _ = reply.send(r);
            }
        }
    }

    /// Configures, then acquires `n` frames into `sink`; counters follow.
    fn acquire(
        &mut self,
        settings: &Acquisition,
        n: usize,
        sink: &SyncSender<RawFrame>,
    ) -> Result<FrameCounts, CameraError> {
        let Some(c) = self.camera.as_mut() else {
            return Err(self.not_connected());
        };
        let r = c.configure(settings);
        self.refresh();
        let Some(c) = self.camera.as_mut() else {
            return Err(self.not_connected());
        };
        // Each frame counts as received when it arrives, not when the
        // acquisition ends (a live view's runs for its whole session).
        let status = &self.status;
        let r = r.and_then(|()| {
            c.acquire(n, &mut |f| {
                if let Ok(mut s) = status.lock() {
                    s.counters.completed += 1;
                }
                sink.send(f).map_err(|_| SinkClosed)
            })
        });
        let k = c.counters();
        let base = self.base;
        self.update(|s| {
            s.counters = Counters {
                connects: s.counters.connects,
                ..add(base, k)
            }
        });
        r
    }

    /// Drops a camera that was lost; the loop reopens it at once.
    fn lose(&mut self, why: String) {
        if let Some(c) = self.camera.take() {
            self.base = add(self.base, c.counters());
        }
        tracing::warn!("camera lost: {why}");
        self.update(|s| {
            s.connected = false;
            s.last_error = Some(why);
        });
        self.backoff = Duration::ZERO;
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
        stream_restarts: a.stream_restarts + b.stream_restarts,
        connects: a.connects,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A camera that delivers 1x1 frames and counts them.
    struct Counting(Counters);

    impl CameraDevice for Counting {
        fn describe(&mut self) -> Result<CameraInfo, CameraError> {
            Err(CameraError::Disconnected(
                "a test camera has no description".into(),
            ))
        }
        fn configure(&mut self, _: &Acquisition) -> Result<(), CameraError> {
            Ok(())
        }
        fn acquire(
            &mut self,
            n: usize,
            sink: &mut super::super::device::FrameSink<'_>,
        ) -> Result<FrameCounts, CameraError> {
            for k in 0..n {
                let frame = RawFrame {
                    width: 1,
                    height: 1,
                    bits: 16,
                    pixels: vec![0],
                    frame_id: k as u64,
                    system_timestamp_ns: 0,
                };
                self.0.completed += 1;
                sink(frame).map_err(CameraError::Stopped)?;
            }
            Ok(FrameCounts {
                received: n as u64,
                ..FrameCounts::default()
            })
        }
        fn counters(&self) -> Counters {
            self.0
        }
    }

    #[test]
    fn frames_received_count_up_while_an_acquisition_runs() {
        let handle = CameraHandle::spawn(Box::new(|| {
            Ok(Box::new(Counting(Counters::default())) as Box<dyn CameraDevice>)
        }));
        // A channel of no room: the camera thread waits for each frame to be taken.
        let (tx, rx) = mpsc::sync_channel(0);
        let status = handle.clone();
        let reader = std::thread::spawn(move || {
            (0..3)
                .map(|_| {
                    rx.recv().expect("a frame");
                    status.status().counters.completed
                })
                .collect::<Vec<_>>()
        });
        let settings = Acquisition::defaults_at([0, 0, 1, 1], [1, 1]);
        let rt = tokio::runtime::Builder::new_current_thread()
            .build()
            .expect("a runtime");
        let got = rt
            .block_on(handle.acquire(settings, 3, tx))
            .expect("3 frames");
        let seen = reader.join().expect("the reader");
        assert_eq!(got.received, 3);
        // The first frame was counted before the other two were sent.
        assert!(seen[0] >= 1 && seen.iter().all(|&n| n <= 3), "{seen:?}");
        assert_eq!(handle.status().counters.completed, 3);
        handle.shutdown();
    }
}
