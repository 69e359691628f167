#!/usr/bin/env bash
# A rustc wrapper (cargo's RUSTC_WORKSPACE_WRAPPER) that compiles as asked,
# then, for the polnlos library itself (not its tests, not the binary),
# documents it with rustdoc from the same inputs, `-D warnings`: a broken or
# private intra-doc link fails the build, as
# `RUSTDOCFLAGS="-D warnings" cargo doc --no-deps --lib` would.
#
# Why not `cargo doc`: it type-checks every dependency again in its own mode
# (71 s on 2 cores after a fresh `cargo test --no-run`), over the
# 12-minute budget of .ci/run. Here rustdoc reads the dependencies the
# build has just compiled (their .rmeta), and costs about 10 s.
# The wrapper is not part of cargo's fingerprint: with or without it, the
# same build is fresh. .ci/run sets it for its build and test command.
set -u
rustc=$1
shift
"$rustc" "$@" || exit $?

args=("$@")
name="" lib=0 out=""
for ((k = 0; k < ${#args[@]}; k++)); do
  case "${args[k]}" in
    --crate-name) name=${args[k + 1]} ;;
    --crate-type) [ "${args[k + 1]}" = lib ] && lib=1 ;;
    --out-dir) out=${args[k + 1]} ;;
    --test) exit 0 ;;
  esac
done
if [ "$name" != polnlos ] || [ "$lib" != 1 ] || [ -z "$out" ]; then
  exit 0
fi

# What rustdoc takes of the compile: the crate, its edition and source, its
# cfgs and the dependencies' paths. Codegen (-C), outputs and message
# formats are the compiler's own.
keep=()
k=0
while [ $k -lt ${#args[@]} ]; do
  a=${args[k]}
  case "$a" in
    --crate-name | --crate-type | --cfg | --check-cfg | -L | --extern)
      keep+=("$a" "${args[k + 1]}")
      k=$((k + 2))
      continue
      ;;
    -C | --out-dir | --error-format | --json | --emit | --cap-lints)
      k=$((k + 2))
      continue
      ;;
    --edition=* | *.rs) keep+=("$a") ;;
  esac
  k=$((k + 1))
done

rustdoc=rustdoc
if [[ $rustc == */* ]] && [ -x "${rustc%/*}/rustdoc" ]; then
  rustdoc="${rustc%/*}/rustdoc"
fi
# target/<profile>/deps -> target/doc, where cargo doc writes.
doc="$(dirname "$(dirname "$out")")/doc"
if ! "$rustdoc" "${keep[@]}" -o "$doc" -D warnings; then
  echo "the library's documentation has errors (above): fix them, then check with" \
    "RUSTDOCFLAGS=\"-D warnings\" cargo doc --no-deps --lib" >&2
  exit 1
fi
