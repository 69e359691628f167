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

fn main() -> ExitCode {
    let args = cli::Cli::parse();
    match cli::run(args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", message(&e));
            ExitCode::from(2)
        }
    }
}
