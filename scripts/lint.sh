#!/usr/bin/env bash
# The maintainers' checks before a commit, beside `cargo test --locked`
# (which .ci/run runs): lints, the build without the daemon, the docs and
# the build with the oldest Rust declared.
# Not in .ci/run: they are minutes of a fresh clone's
# 12-minute budget (docs/test-times.md).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo fmt --check
# The declared rust-version covers the locked dependencies (seconds).
python3 scripts/msrv.py
cargo clippy --locked --all-targets -- -D warnings
# The numeric core and the offline tools build without the daemon's
# libraries (Aravis, SQLite, tokio, axum).
cargo check --locked --no-default-features --lib --bins
# The library's documentation builds with no broken or private link.
RUSTDOCFLAGS="-D warnings" cargo doc --locked --no-deps --lib
# The oldest Rust the crates declare builds them (a minute once its own
# target folder is warm; the first run fetches and builds, about 7 minutes).
scripts/msrv-build.sh
