#!/usr/bin/env python3
"""Revision 3 against revision 2 at equal exposure, through camera frames.

For each pattern and photon count: `polnlos simulate --frames` draws camera
frames pixel by pixel (each pixel at its own wall point, per-pixel shot and
read noise); then
  - revision 3: `polnlos measure` (every pixel of an element, footprint-weighted,
    its variance propagated) and `polnlos reconstruct` with that variance;
  - revision 2: the same frames sampled once per element, bilinearly at the
    element centre's image H(u_c, v_c), as polnlos did before revision 3
    (written out here in numpy), its variance sampled the same way, and the
    same `polnlos reconstruct`.
Both with the automatic lambda, both in units of T l (`frame_gain`).

    python3 validation/equal_exposure.py [--polnlos target/release/polnlos] [--scene brewster-crossed]

Prints one row per case: PSNR of each path and the difference.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def run(cmd):
    r = subprocess.run([str(c) for c in cmd], capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"{' '.join(map(str, cmd))} failed:\n{r.stderr}")
    return r.stdout


def read_tiff_pages(path: Path) -> np.ndarray:
    """Every page of a 16-bit grey TIFF as float64 (frames, height, width)."""
    from PIL import Image  # pillow reads multi-page 16-bit grey TIFF

    im = Image.open(path)
    pages = []
    for k in range(getattr(im, "n_frames", 1)):
        im.seek(k)
        pages.append(np.array(im, dtype=np.float64))
    return np.stack(pages)


def bilinear(frame: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    x1, y1 = np.minimum(x0 + 1, frame.shape[1] - 1), np.minimum(y0 + 1, frame.shape[0] - 1)
    top = frame[y0, x0] * (1 - fx) + frame[y0, x1] * fx
    bot = frame[y1, x0] * (1 - fx) + frame[y1, x1] * fx
    return top * (1 - fy) + bot * fy


def centre_samples(scene: dict, pose: dict, mean: np.ndarray, var: np.ndarray):
    nu, nv = scene["wall"]["grid"]
    su, sv = scene["wall"]["size"]
    iu, iv = np.meshgrid(np.arange(nu), np.arange(nv))
    u = ((iu.ravel() + 0.5) / nu - 0.5) * su
    v = ((iv.ravel() + 0.5) / nv - 0.5) * sv
    h = np.array(pose["homography"], dtype=float)
    p = h @ np.stack([u, v, np.ones_like(u)])
    x, y = p[0] / p[2], p[1] / p[2]
    return bilinear(mean, x, y), bilinear(var, x, y)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--polnlos", default=str(ROOT / "target/release/polnlos"))
    ap.add_argument("--scene", default="brewster-crossed")
    ap.add_argument("--photons", type=float, nargs="+", default=[1e3, 1e4])
    ap.add_argument("--patterns", nargs="+", default=["disk", "bars", "letter"])
    ap.add_argument("--frames", type=int, default=4)
    a = ap.parse_args()
    scene_file = ROOT / "config/scenes" / f"{a.scene}.toml"
    scene = tomllib.loads(scene_file.read_text())
    print(f"scene {a.scene}, {a.frames} frames a block, automatic lambda")
    print(f"{'pattern':8} {'e-/pixel':>9} {'rev 2 (centre)':>15} {'rev 3 (pixels)':>15} {'gain':>7}")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for pattern in a.patterns:
            truth = tmp / f"{pattern}.png"
            run([a.polnlos, "pattern", pattern, "--size", "64", "--out", truth])
            for photons in a.photons:
                sim = tmp / f"sim-{pattern}-{photons:g}"
                run([a.polnlos, "simulate", scene_file, "--truth", truth, "--out", sim,
                     "--photons", photons, "--frames", "--frame-count", a.frames, "--seed", 7])
                meta = json.loads((sim / "simulate.json").read_text())
                gain = meta["frame_gain"]
                blocks = meta["blocks"]
                frames_args, poses, angles = [], [], []
                i2, v2 = [], []
                for b in blocks:
                    label = b["frame_png"].removeprefix("frame-").removesuffix(".png")
                    path = sim / f"frames-{label}.tiff"
                    frames_args += ["--frames", path]
                    poses += ["--pose", b["pose"]]
                    angles += ["--angle", "none" if b["polarizer_deg"] is None else b["polarizer_deg"]]
                    pages = read_tiff_pages(path)
                    full = 2 ** meta["noise"]["bits"] - 1
                    mean = pages.mean(0)
                    var = pages.var(0, ddof=1) / pages.shape[0]
                    pose = next(p for p in scene["pose"] if p["name"] == b["pose"])
                    m, v = centre_samples(scene, pose, mean, var)
                    i2.append(m / full / gain)
                    v2.append(v / full**2 / gain**2)
                # Revision 3: polnlos measure.
                i3 = sim / "i3.npy"
                run([a.polnlos, "measure", scene_file, *frames_args, *poses, *angles,
                     "--exposure-us", 1, "--gain", gain, "--out", i3])
                psnr = {}
                for name, meas, var in [
                    ("rev3", i3, sim / "i3.variance.npy"),
                    ("rev2", sim / "i2.npy", sim / "i2.variance.npy"),
                ]:
                    if name == "rev2":
                        np.save(meas, np.concatenate(i2))
                        np.save(var, np.concatenate(v2))
                    out = sim / f"rec-{name}"
                    run([a.polnlos, "reconstruct", scene_file, "--measurement", meas,
                         "--variance", var, "--truth", sim / "truth.npy", "--out", out])
                    psnr[name] = json.loads((out / "report.json").read_text())["metrics"]["psnr_db"]
                print(f"{pattern:8} {photons:>9g} {psnr['rev2']:>12.2f} dB {psnr['rev3']:>12.2f} dB "
                      f"{psnr['rev3'] - psnr['rev2']:>+6.2f}")


if __name__ == "__main__":
    main()
