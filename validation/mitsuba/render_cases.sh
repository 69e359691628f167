#!/usr/bin/env bash
# Regenerate every Mitsuba-rendered case under tests/data/rendered/ from the
# scene.toml found in each case directory (truth = the letter F on its scene grid).
# One render process at a time. Extra arguments go to render.py, e.g.
#   validation/mitsuba/render_cases.sh --spp 8192
# Each case gets its own fixed seed (from its name), so a rerun reproduces it.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
repo="$(cd "$here/../.." && pwd)"
: "${DRJIT_LIBLLVM_PATH:=/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1}"
export DRJIT_LIBLLVM_PATH
start=$(date +%s)
for dir in "$repo"/tests/data/rendered/*/; do
    [ -f "$dir/scene.toml" ] || continue
    name="$(basename "$dir")"
    seed=$(printf '%s' "$name" | cksum | cut -d' ' -f1)
    echo "== $name (seed $seed)"
    python3 "$here/render.py" "$dir/scene.toml" --pattern letter --out "$dir" --seed "$seed" "$@"
done
echo "all cases in $(( $(date +%s) - start )) s"
