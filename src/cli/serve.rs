//! `polnlos serve`: the acquisition daemon.

use std::path::PathBuf;

use anyhow::Context;
use polnlos::daemon::{Config, Daemon};
use polnlos::transport::MemoryBudget;

/// Run the acquisition daemon (camera, queues, HTTP API).
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Without --config the embedded default runs: Aravis's GigE Vision fake camera on 127.0.0.1 \
showing a demo hidden scene, the API on 127.0.0.1:8470, data in ./polnlos-data.\n\
Example:\n  polnlos serve\n  curl -s localhost:8470/health"
)]
pub struct Args {
    /// Configuration file (TOML; start from config/polnlos.toml).
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Address to serve the API on (overrides the config).
    #[arg(long, value_name = "ADDR:PORT")]
    bind: Option<std::net::SocketAddr>,
    /// Data directory (overrides the config).
    #[arg(long = "data-dir", value_name = "DIR")]
    data_dir: Option<PathBuf>,
}

pub fn run(a: Args, budget: MemoryBudget) -> anyhow::Result<()> {
    use std::io::IsTerminal;
    // Colour only on a terminal: not into log files or journald.
    use tracing_subscriber::layer::SubscriberExt;
    use tracing_subscriber::util::SubscriberInitExt;
    // `RUST_LOG` as `info,polnlos::daemon=debug` (targets and levels; not
    // env-filter's span and field matches, whose regex engine was 14 s of
    // a fresh build): unset or unreadable, `info`, and a word on the latter.
    let (targets, unreadable) =
        polnlos::daemon::log_targets(std::env::var("RUST_LOG").ok().as_deref());
    tracing_subscriber::fmt()
        .with_ansi(std::io::stderr().is_terminal())
        .with_writer(std::io::stderr)
        .finish()
        .with(targets)
        .init();
    if let Some(e) = unreadable {
        tracing::warn!(error = %e, "RUST_LOG is not a list of target=level directives; logging at info");
    }
    let mut config = match &a.config {
        Some(p) => Config::load(p)?,
        None => Config::embedded(),
    };
    if let Some(b) = a.bind {
        config.bind = b;
    }
    if let Some(d) = a.data_dir {
        config.data_dir = d;
    }
    // Two cores: two async workers for I/O; the maths runs on blocking threads and rayon.
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    rt.block_on(serve(config, budget))
}

async fn serve(config: Config, budget: MemoryBudget) -> anyhow::Result<()> {
    let bind = config.bind;
    // The signal handlers before anything answers: a SIGTERM that came
    // between the first answer and the handler's first poll killed the
    // daemon outright (a test under load saw it exit by signal 15).
    let stop = shutdown_signal()?;
    let mut hangup = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::hangup())
        .context("cannot handle SIGHUP")?;
    // The port first: a second daemon fails here, or on the data directory's
    // lock, before it touches anything of the first one's.
    let listener = tokio::net::TcpListener::bind(bind)
        .await
        .with_context(|| format!("cannot listen on {bind}"))?;
    let daemon = Daemon::start(config, budget).await?;
    tracing::info!("polnlos API on http://{}", listener.local_addr()?);
    notify(&[sd_notify::NotifyState::Ready]);
    // SIGHUP reads the scene files again; running jobs keep their scenes.
    let reloading = daemon.clone();
    let reload = tokio::spawn(async move {
        while hangup.recv().await.is_some() {
            let d = reloading.clone();
            if let Err(e) = tokio::task::spawn_blocking(move || d.reload_scenes()).await {
                tracing::error!("reading the scenes again failed: {e}");
            }
        }
    });
    let watchdog = watchdog();
    let result = polnlos::api::run(listener, daemon, async {
        stop.await;
        notify(&[sd_notify::NotifyState::Stopping]);
    })
    .await;
    if let Some(w) = watchdog {
        w.abort();
    }
    reload.abort();
    result.context("HTTP server stopped")
}

fn notify(state: &[sd_notify::NotifyState<'_>]) {
    if let Err(e) = sd_notify::notify(false, state) {
        tracing::debug!("sd_notify: {e}");
    }
}

/// Pings systemd's watchdog at half its interval when the unit asks for one.
fn watchdog() -> Option<tokio::task::JoinHandle<()>> {
    let mut usec = 0;
    if !sd_notify::watchdog_enabled(false, &mut usec) || usec == 0 {
        return None;
    }
    let period = std::time::Duration::from_micros(usec / 2);
    Some(tokio::spawn(async move {
        loop {
            notify(&[sd_notify::NotifyState::Watchdog]);
            tokio::time::sleep(period).await;
        }
    }))
}

/// SIGINT or SIGTERM, registered now (when this returns) rather than when
/// the future is first polled, so that a signal sent as soon as the daemon
/// answers stops it cleanly.
fn shutdown_signal() -> anyhow::Result<impl std::future::Future<Output = ()>> {
    use tokio::signal::unix::{signal, SignalKind};
    let mut int = signal(SignalKind::interrupt()).context("cannot handle SIGINT")?;
    let mut term = signal(SignalKind::terminate()).context("cannot handle SIGTERM")?;
    Ok(async move {
        tokio::select! { _ = int.recv() => {}, _ = term.recv() => {} }
        tracing::info!("shutting down");
    })
}
