#!/usr/bin/env bash
# Checks polnlos with the oldest Rust it declares (`rust-version` in
# Cargo.toml), so that a lab's older toolchain is known to build it rather
# than assumed: scripts/msrv.py holds the locked dependencies' declared
# versions to it, clippy's incompatible_msrv lint our use of std, and this
# compiles everything with that rustc (every target, the build without the
# daemon, the Python extension). rustup fetches the toolchain when it is
# missing. Its own target folder leaves the main build untouched: about 7
# minutes the first time on 2 cores, under a minute after a change.
set -euo pipefail
cd "$(dirname "$0")/.."
version=$(sed -n 's/^rust-version = "\(.*\)"$/\1/p' Cargo.toml | head -n 1)
if [ -z "$version" ]; then
  echo "Cargo.toml declares no rust-version" >&2
  exit 1
fi
rustup toolchain install "$version" --profile minimal --no-self-update
export CARGO_TARGET_DIR="$PWD/target/msrv"
cargo "+$version" check --locked --all-targets
cargo "+$version" check --locked --no-default-features --lib --bins
(cd python && cargo "+$version" check --locked)
echo "rust $version builds polnlos"
