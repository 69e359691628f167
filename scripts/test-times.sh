#!/usr/bin/env bash
# Per-test times of the whole suite (docs/test-times.md): builds what
# `cargo test --locked` builds, then runs each test binary one after the
# other as cargo does (working directory: the crate root), with libtest's
# JSON report and its per-test times (four test threads, as .cargo/config.toml sets). Writes OUT/<binary>.json and
# OUT/binaries.txt (wall seconds per binary).
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-target/test-times}
mkdir -p "$out"
: > "$out/binaries.txt"
cargo test --locked --no-run --message-format=json 2>/dev/null | python3 -c '
import sys, json
for line in sys.stdin:
    try:
        m = json.loads(line)
    except ValueError:
        continue
    if m.get("reason") == "compiler-artifact" and m.get("executable") and m["profile"]["test"]:
        kind = m["target"]["kind"][0]
        print(m["target"]["name"] + ("" if kind == "test" else "-" + kind), m["executable"])
' > "$out/bins.txt"
while read -r name exe; do
  start=$(date +%s.%N)
  RUST_TEST_THREADS=${RUST_TEST_THREADS:-4} RUSTC_BOOTSTRAP=1 "$exe" -Zunstable-options --format json --report-time \
    > "$out/$name.json" 2> "$out/$name.err" < /dev/null || true
  end=$(date +%s.%N)
  python3 -c "print('$name', round($end - $start, 1))" | tee -a "$out/binaries.txt"
done < "$out/bins.txt"
