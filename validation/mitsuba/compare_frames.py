#!/usr/bin/env python3
"""Compare Mitsuba camera frames (render.py --frames) with model.py's T l (MODEL.md rev 3).

    python3 validation/mitsuba/compare_frames.py tests/data/rendered/crossed/frames [...] \
        [--wall-supersample 1 4 8] [--scene-supersample N] [--json OUT.json] [--cache DIR]

Per case: i = measure(frame-k, H of block k's pose) (model.py, MODEL.md "From camera
frames to i"), noise sigma_j = sqrt(var_j) from frame-sigma-k propagated through measure,
and the predictions T l with `"uniform"` rows at each wall supersample m and with
`"pixels"` rows (the scene side at the file's scene supersample, or --scene-supersample).
Printed per prediction, over all blocks: rms(i - T l)/rms(i) and max|i - T l|/rms(i), the
largest per-element relative difference max |i - T l|/i, rms and max of (i - T l)/sigma,
and the excess over the noise sqrt(rms(i - T l)^2 - rms(sigma)^2)/rms(i);
the noise line gives rms(sigma)/rms(i), max sigma_j/i_j.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import model  # noqa: E402


def rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


def case(d, wall_ms, scene_m=None, cache=None):
    d = Path(d)
    sc = model.load(d / "scene.toml", scene_supersample=scene_m)
    truth = np.load(d / "truth.npy").reshape(-1)
    cols = np.flatnonzero(truth)
    l = truth[cols]
    poses = [p for p in sc["poses"] for _ in (p["deg"] or [None])]
    i, var = [], []
    for k, p in enumerate(poses):
        f = np.load(d / f"frame-{k}.npy")
        s = np.load(d / f"frame-sigma-{k}.npy").astype(np.float64)
        ik, vk = model.measure(f, p["H"], sc["wall"], variance=s ** 2)
        i.append(ik)
        var.append(vk)
    i, sig = np.concatenate(i), np.sqrt(np.concatenate(var))
    out = {"case": str(d), "rows": int(len(i)), "scene_supersample": sc["scene"]["m"],
           "noise_rel_rms": rms(sig) / rms(i), "noise_rel_max": float(np.max(sig / i)), "pred": {}}
    preds = [(f"uniform m={m}", "uniform", m) for m in wall_ms] + [("pixels", "pixels", None)]
    for label, sampling, m in preds:
        f = None if cache is None else Path(cache) / f"{d.parent.name}-{d.name}-{sampling}-{m}-{sc['scene']['m']}.npy"
        if f is not None and f.exists():
            pred = np.load(f)
        else:
            s2 = model.load(d / "scene.toml", scene_supersample=scene_m, wall_supersample=m)
            T, _ = model.transport(s2, sampling, cols=cols)
            pred = T @ l
            if f is not None:
                f.parent.mkdir(parents=True, exist_ok=True)
                np.save(f, pred)
        r = i - pred
        out["pred"][label] = {
            "rel_rms": rms(r) / rms(i), "max_over_rms": float(np.max(np.abs(r)) / rms(i)),
            "max_rel": float(np.max(np.abs(r) / i)), "chi_rms": rms(r / sig),
            "chi_max": float(np.max(np.abs(r) / sig)),
            "excess_rel_rms": float(np.sqrt(max(0.0, rms(r) ** 2 - rms(sig) ** 2))) / rms(i),
            "gain": float(pred @ i / (pred @ pred)),
        }
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cases", nargs="+")
    ap.add_argument("--wall-supersample", type=int, nargs="+", default=[1, 4, 8])
    ap.add_argument("--scene-supersample", type=int, default=None)
    ap.add_argument("--json", default=None)
    ap.add_argument("--cache", default=None, help="directory for the predictions T l (reused when present)")
    a = ap.parse_args()
    res = []
    for c in a.cases:
        r = case(c, a.wall_supersample, a.scene_supersample, a.cache)
        res.append(r)
        print(f"{c}: {r['rows']} rows, scene supersample {r['scene_supersample']}, noise rms "
              f"{100 * r['noise_rel_rms']:.3f} % (max sigma/i {100 * r['noise_rel_max']:.3f} %)")
        for k, p in r["pred"].items():
            print(f"  {k:>12}: rms {100 * p['rel_rms']:.3f} %  max {100 * p['max_over_rms']:.3f} % of rms(i)"
                  f"  max per element {100 * p['max_rel']:.3f} %  resid/sigma rms {p['chi_rms']:.2f}"
                  f" max {p['chi_max']:.1f}  excess over noise {100 * p['excess_rel_rms']:.3f} %  gain {p['gain']:.5f}")
        sys.stdout.flush()
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=1) + "\n")


if __name__ == "__main__":
    main()
