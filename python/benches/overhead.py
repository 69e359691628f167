"""The Python bindings' overhead against the same Rust call.

A 32x32 hidden scene on the reference bench (brewster-crossed with its scene
grid raised to 32x32: T is 1024 x 1024), reconstructed with ADMM-TV at a
fixed λ: `polnlos.reconstruct` from Python against `reconstruct_scene` timed
inside Rust with no Python in between (`_polnlos.rust_reconstruct_seconds`).
Calls alternate (Python, Rust, Python, ...) so that drift on a shared machine
falls on both; the overhead is the ratio of the medians.

    python3 python/benches/overhead.py [--repeat 15] [--out docs/bench/python-overhead.md]
"""

import argparse
import json
import pathlib
import platform
import statistics
import time

import numpy as np

import polnlos
from polnlos import _polnlos

ROOT = pathlib.Path(__file__).resolve().parents[2]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=15)
    ap.add_argument("--out", type=pathlib.Path, default=ROOT / "docs/bench/python-overhead.md")
    a = ap.parse_args()

    text = (ROOT / "config/scenes/brewster-crossed.toml").read_text()
    assert "grid = [8, 8]" in text
    scene = polnlos.Scene.from_toml(text.replace("grid = [8, 8]", "grid = [32, 32]"),
                                    name="brewster-crossed-32x32")
    truth = polnlos.pattern("letter", scene)
    i, _ = polnlos.simulate(scene, truth, photons=1e6, seed=1)
    lam = 1e-9
    polnlos.reconstruct(scene, i, lam=lam)  # warm-up (thread pool, page faults)
    py, rs = [], []
    for _ in range(a.repeat):
        t = time.perf_counter()
        polnlos.reconstruct(scene, i, lam=lam)
        py.append(time.perf_counter() - t)
        rs.extend(_polnlos.rust_reconstruct_seconds(scene, i, lam, 1))
    mp, mr = statistics.median(py), statistics.median(rs)
    overhead = mp / mr - 1
    result = {
        "scene": scene.name,
        "T": [scene.rows, scene.cols],
        "repeat": a.repeat,
        "python_median_s": mp,
        "rust_median_s": mr,
        "python_s": py,
        "rust_s": rs,
        "overhead": overhead,
        "machine": f"{platform.machine()}, {platform.python_implementation()} {platform.python_version()}",
    }
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.with_suffix(".json").write_text(json.dumps(result, indent=1) + "\n")
    a.out.write_text(f"""# The Python bindings' overhead

`python3 python/benches/overhead.py` (this page is its output). {scene.name}:
T {scene.rows} x {scene.cols}, ADMM-TV at λ = {lam:g}, {a.repeat} calls each,
alternating. Python: `polnlos.reconstruct(scene, i, lam=...)` (the NumPy
measurement in, the image array and the report dict out). Rust: the same
`reconstruct_scene` call timed inside Rust.

| | median | min | max |
|---|---|---|---|
| Python `polnlos.reconstruct` | {mp * 1e3:.1f} ms | {min(py) * 1e3:.1f} ms | {max(py) * 1e3:.1f} ms |
| Rust `reconstruct_scene` | {mr * 1e3:.1f} ms | {min(rs) * 1e3:.1f} ms | {max(rs) * 1e3:.1f} ms |

Overhead of the bindings: **{overhead * 100:+.2f} %** of the Rust call (the
target is under 5 %). Machine: {result['machine']}, 2 cores.
""")
    print(f"python {mp * 1e3:.1f} ms, rust {mr * 1e3:.1f} ms, overhead {overhead * 100:+.2f} %")


if __name__ == "__main__":
    main()
