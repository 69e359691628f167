#!/usr/bin/env bash
# Per-test times of the whole suite (docs/test-times.md): builds what
# `cargo test --locked` builds, then runs each test binary one after the
# other as cargo does (working directory: the crate root), with libtest's
# JSON report and its per-test times (twenty test threads, as .cargo/config.toml sets). Writes OUT/<binary>.json,
# OUT/<binary>.times (when each test started and ended), OUT/aravis.tsv (each
# hold of the daemon tests' Aravis lock) and OUT/binaries.txt (wall seconds
# per binary).
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-target/test-times}
mkdir -p "$out"
out=$(cd "$out" && pwd)
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
: > "$out/aravis.tsv"
while read -r name exe; do
  start=$(date +%s.%N)
  RUST_TEST_THREADS=${RUST_TEST_THREADS:-20} RUSTC_BOOTSTRAP=1 POLNLOS_ARAVIS_LOG="$out/aravis.tsv" \
    "$exe" -Zunstable-options --format json --report-time 2> "$out/$name.err" < /dev/null \
    | python3 -c '
import sys, time, json
# Each line as libtest wrote it, and beside it when each test started and
# ended (Unix seconds), for the timeline in docs/test-times.md.
json_out, times = open(sys.argv[1], "w"), open(sys.argv[2], "w")
for line in sys.stdin:
    json_out.write(line); json_out.flush()
    try:
        e = json.loads(line)
    except ValueError:
        continue
    if e.get("type") == "test" and e.get("event") in ("started", "ok", "failed"):
        times.write("%.2f\t%s\t%s\n" % (time.time(), e["event"], e["name"])); times.flush()
' "$out/$name.json" "$out/$name.times" || true
  end=$(date +%s.%N)
  python3 -c "print('$name', round($end - $start, 1))" | tee -a "$out/binaries.txt"
done < "$out/bins.txt"
