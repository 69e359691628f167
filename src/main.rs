//! The `polnlos` command: offline tools on scene files, and the daemon.

mod cli;

use std::process::ExitCode;

use clap::Parser;

/// The error and its causes, each said once: the library's messages already
/// quote their source (a file's OS error), so a cause whose text the message
/// before it contains is not repeated.
fn message(e: &anyhow::Error) -> String {
    let mut out = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if !out.contains(&text) {
            if !out.is_empty() {
                out.push_str(": ");
            }
            out.push_str(&text);
        }
    }
    out
}

/// Exit status of a command that finished its work.
const DONE: u8 = 0;
/// The input was fine but the work could not be finished: a camera lost, a
/// solver that failed, a disk that filled while writing results.
const FAILED: u8 = 1;
/// The command line is wrong (clap's own code), or it asks for something
/// another process already holds (a data directory served by another daemon).
const USAGE: u8 = 2;
/// A file the user named is wrong: a scene, a measurement, an image, the
/// config or the data directory is missing, unreadable, malformed or out of
/// range (including a scene too large for this machine's memory).
const INPUT: u8 = 3;

/// The exit status of a daemon-side cause (the daemon, its store, its
/// config), if it is one.
#[cfg(feature = "daemon")]
fn daemon_exit_code(cause: &(dyn std::error::Error + 'static)) -> Option<u8> {
    use polnlos::daemon::DaemonError;
    use polnlos::store::StoreError;
    // DaemonError is transparent over these: its source skips them.
    let store = match cause.downcast_ref::<DaemonError>() {
        Some(DaemonError::Store(s)) => Some(s),
        Some(DaemonError::Config(_) | DaemonError::Scene(_)) => return Some(INPUT),
        Some(DaemonError::Fake(polnlos::camera::fake::FakeError::AddressInUse { .. })) => {
            return Some(USAGE)
        }
        Some(
            DaemonError::Demo(_)
            | DaemonError::Fake(_)
            | DaemonError::Mount(_)
            | DaemonError::Light(_),
        ) => return Some(FAILED),
        None => cause.downcast_ref::<StoreError>(),
    };
    if let Some(s) = store {
        return Some(match s {
            StoreError::Locked { .. } => USAGE,
            StoreError::DataDir { .. } | StoreError::Database { .. } => INPUT,
            _ => FAILED,
        });
    }
    cause.is::<polnlos::daemon::ConfigError>().then_some(INPUT)
}

/// The exit status of an error, from the first cause that says whose it is.
fn exit_code(e: &anyhow::Error) -> u8 {
    e.chain().find_map(code_of).unwrap_or(FAILED)
}

/// The exit status one cause says, when it says one.
fn code_of(cause: &(dyn std::error::Error + 'static)) -> Option<u8> {
    use polnlos::files::FileError;
    use polnlos::measure::given::GivenError;
    use polnlos::solve::scene::SceneSolveError;
    use polnlos::solve::SolveError;
    use polnlos::transport::TransportError;
    #[cfg(feature = "daemon")]
    if let Some(code) = daemon_exit_code(cause) {
        return Some(code);
    }
    // The library's combined errors are their inner error's.
    if let Some(e) = cause.downcast_ref::<SceneSolveError>() {
        return match e {
            SceneSolveError::Transport(t) => code_of(t),
            SceneSolveError::Solve(s) => code_of(s),
        };
    }
    if let Some(e) = cause.downcast_ref::<GivenError>() {
        return match e {
            GivenError::Measure(m) => code_of(m),
            GivenError::Transport(t) => code_of(t),
            GivenError::Solve(s) => code_of(s),
            GivenError::Gain(_) => Some(USAGE),
        };
    }
    if let Some(f) = cause.downcast_ref::<FileError>() {
        return Some(match f {
            FileError::Format { .. } => INPUT,
            FileError::Io { action, .. } if action.starts_with("cannot read") => INPUT,
            FileError::Io { .. } => FAILED,
        });
    }
    if let Some(t) = cause.downcast_ref::<polnlos::files::truth::TruthError>() {
        return match t {
            polnlos::files::truth::TruthError::File(f) => code_of(f),
            _ => Some(INPUT),
        };
    }
    if let Some(t) = cause.downcast_ref::<TransportError>() {
        return Some(match t {
            TransportError::Parameter { .. } => USAGE,
            TransportError::TooLarge { .. }
            | TransportError::NoHomography { .. }
            | TransportError::Footprint(_)
            | TransportError::ActivePixels
            | TransportError::ActiveArea
            | TransportError::Choice(_) => INPUT,
            TransportError::Stopped { .. } => FAILED,
        });
    }
    if let Some(s) = cause.downcast_ref::<SolveError>() {
        return Some(match s {
            SolveError::Parameter { .. } => USAGE,
            SolveError::Length { .. } | SolveError::NonFinite { .. } => INPUT,
            _ => FAILED,
        });
    }
    if let Some(s) = cause.downcast_ref::<polnlos::simulate::SimulateError>() {
        return Some(match s {
            polnlos::simulate::SimulateError::Parameter { .. } => USAGE,
            polnlos::simulate::SimulateError::Black => INPUT,
        });
    }
    if let Some(o) = cause.downcast_ref::<polnlos::calibrate::occluder::OccluderError>() {
        use polnlos::calibrate::occluder::OccluderError as E;
        return match o {
            E::Index { .. } | E::NoneSelected | E::Parameter { .. } => Some(USAGE),
            E::Transport(t) => code_of(t),
            E::Solve(s) => code_of(s),
            _ => Some(INPUT),
        };
    }
    if let Some(o) = cause.downcast_ref::<polnlos::calibrate::scene::SceneFitError>() {
        use polnlos::calibrate::scene::SceneFitError as E;
        return match o {
            E::NothingFree | E::NoOccluders(_) | E::Parameter { .. } => Some(USAGE),
            E::Selection(s) => code_of(s),
            E::Transport(t) => code_of(t),
            E::Solve(s) => code_of(s),
            E::Stopped => Some(FAILED),
            _ => Some(INPUT),
        };
    }
    if cause.is::<polnlos::calibrate::geometry::CalibrationError>()
        || cause.is::<polnlos::calibrate::wall::WallFitError>()
        || cause.is::<polnlos::measure::MeasureError>()
        || cause.is::<polnlos::scene::SceneError>()
    {
        return Some(INPUT);
    }
    cause.is::<cli::Usage>().then_some(USAGE)
}

fn main() -> ExitCode {
    let args = cli::Cli::parse();
    match cli::run(args) {
        Ok(()) => ExitCode::from(DONE),
        Err(e) => {
            eprintln!("error: {}", message(&e));
            ExitCode::from(exit_code(&e))
        }
    }
}
