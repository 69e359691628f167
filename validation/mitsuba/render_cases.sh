#!/usr/bin/env bash
# Regenerate every Mitsuba-rendered case under tests/data/rendered/ from the
# scene.toml found in each case directory (truth = the letter F on its scene grid).
# One render process at a time. Extra arguments go to render.py, e.g.
#   validation/mitsuba/render_cases.sh --spp 8192
# Each case gets its own fixed seed (from its name), so a rerun reproduces it.
#
#   validation/mitsuba/render_cases.sh frames [extra render.py args]
# instead renders the camera frames of every tests/data/rendered/<case>/frames/scene.toml
# (render.py --frames 512 512, spp per pixel from the table below, seed from "<case>-frames")
# into that frames/ directory, then prints compare_frames.py's table.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
repo="$(cd "$here/../.." && pwd)"
: "${DRJIT_LIBLLVM_PATH:=/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1}"
export DRJIT_LIBLLVM_PATH
start=$(date +%s)
if [ "${1:-}" = "frames" ]; then
    shift
    # spp per pixel: a wall element's mean (~70 pixels) at ~0.2 % relative standard error
    declare -A spp=([crossed]=256 [rotating]=512 [multi]=512 [occluder-crossed]=1024)
    dirs=()
    for dir in "$repo"/tests/data/rendered/*/frames/; do
        [ -f "$dir/scene.toml" ] || continue
        name="$(basename "$(dirname "$dir")")"
        seed=$(printf '%s' "$name-frames" | cksum | cut -d' ' -f1)
        echo "== $name frames (seed $seed, spp ${spp[$name]:-512})"
        nice -n 10 python3 "$here/render.py" "$dir/scene.toml" --pattern letter --out "$dir" --seed "$seed" \
            --frames 512 512 --spp "${spp[$name]:-512}" "$@"
        dirs+=("$dir")
    done
    echo "all frames in $(( $(date +%s) - start )) s"
    nice -n 10 python3 "$here/compare_frames.py" "${dirs[@]}"
    exit 0
fi
for dir in "$repo"/tests/data/rendered/*/; do
    [ -f "$dir/scene.toml" ] || continue
    name="$(basename "$dir")"
    seed=$(printf '%s' "$name" | cksum | cut -d' ' -f1)
    echo "== $name (seed $seed)"
    python3 "$here/render.py" "$dir/scene.toml" --pattern letter --out "$dir" --seed "$seed" "$@"
done
echo "all cases in $(( $(date +%s) - start )) s"
