#!/usr/bin/env python3
"""Write the MODEL.md revision-3 reference data under tests/data/rev3/ with model.py.

    python3 validation/mitsuba/make_rev3.py [--out tests/data/rev3]

Independent of the Rust crate: model.py is a separate numpy reading of MODEL.md.
  <case>/scene.toml  a config/scenes/ file with `sampling = "pixels"` under [wall]
                     (and the listed edits), <case>/T.npy its T (float64, rows x cols,
                     MODEL.md row order), <case>/margins.json how close any pixel's wall
                     point comes to an element border and any scene->wall segment to an
                     occluder's edge (the data are only as unambiguous as these margins).
  measure/           a synthetic 512x512 frame, its variance frame, pose A's homography
                     of brewster-crossed and measure()'s i, var, per-element pixel counts,
                     footprint sums and the pixel -> element map.
"""
from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import model  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]

# case name -> (config scene, {key in [wall] / [scene]: new value}, note)
CASES = {
    "brewster-crossed-3x3-pixels": ("brewster-crossed-3x3.toml", {}, "pose A, crossed"),
    "occluder-rotating-3x3-pixels": ("occluder-rotating-3x3.toml", {}, "pose A, 0/45/90/135 deg, occluder"),
    "brewster-multi-3x3-pixels": ("brewster-multi-3x3.toml", {}, "poses B and C, crossed"),
    "occluder-multi-3x3-pixels-kd": (
        "occluder-multi-3x3.toml",
        {("wall", "kd"): "0.1", ("wall", "supersample"): "4", ("scene", "supersample"): "2"},
        "poses B and C, occluder, kd 0.1 (fresnel diffuse), scene supersample 2; wall supersample 4 "
        "must NOT change the pixel rows"),
}


def edit_scene(text, edits, name, src):
    """Insert `sampling = "pixels"` as the last key of [wall] and apply edits (section, key)."""
    out, section = [], None
    lines = text.splitlines()
    for k, line in enumerate(lines):
        m = re.match(r"^\s*\[+\s*([A-Za-z_]+)\s*\]+", line)
        if m:
            section = m.group(1)
        km = re.match(r"^(\s*)([A-Za-z_]+)(\s*=\s*)([^#]*?)(\s*(#.*)?)$", line)
        if km and section and (section, km.group(2)) in edits:
            line = f"{km.group(1)}{km.group(2)}{km.group(3)}{edits[(section, km.group(2))]}"
        out.append(line)
        nxt = lines[k + 1] if k + 1 < len(lines) else "["
        if section == "wall" and (nxt.strip() == "" or nxt.lstrip().startswith("[")) and line.strip():
            out.append('sampling = "pixels"')
            section = "wall-done"
    head = (f"# MODEL.md revision-3 reference case '{name}' (validation/mitsuba/make_rev3.py):\n"
            f"# config/scenes/{src} with sampling = \"pixels\""
            + "".join(f"; {s}.{k} = {v}" for (s, k), v in edits.items()) + ".\n")
    return head + "\n".join(out) + "\n"


def occluder_margin(sc, P):
    """Smallest |max(|a|,|b|) - 1| over segments scene sub-sample -> P crossing a rect's plane
    strictly inside the segment (a, b: the crossing in half-extent units); inf without rects."""
    S = model.samples(sc["scene"]).reshape(-1, 3)
    best = np.inf
    for oc in sc["occluders"]:
        if oc[0] != "rect":
            continue
        _, ce, hu, hv = oc
        nrm = np.cross(hu, hv)
        gi = np.linalg.inv(np.array([[hu @ hu, hu @ hv], [hu @ hv, hv @ hv]]))
        for s in S:
            D = P - s
            t = ((ce - s) @ nrm) / (D @ nrm)
            ok = (t > 0) & (t < 1)
            X = s + t[:, None] * D - ce
            ab = np.stack([X @ hu, X @ hv], -1) @ gi.T
            r = np.abs(np.max(np.abs(ab), axis=1) - 1)[ok]
            if r.size:
                best = min(best, float(r.min()))
    return best


def make_case(out, name, src, edits, note):
    d = out / name
    d.mkdir(parents=True, exist_ok=True)
    text = edit_scene((ROOT / "config/scenes" / src).read_text(), edits, name, src)
    (d / "scene.toml").write_text(text)
    sc = model.load(d / "scene.toml")
    assert sc["sampling"] == "pixels"
    T, labels = model.transport(sc, None)
    np.save(d / "T.npy", np.ascontiguousarray(T, dtype=np.float64))
    marg = {"blocks": [[p, a] for p, a in labels], "shape": list(T.shape), "note": note, "poses": {}}
    for p in sc["poses"]:
        pm = model.pixel_map(p["H"], sc["wall"])
        w = sc["wall"]
        P = w["c"] + pm["u"][:, None] * w["u"] + pm["v"][:, None] * w["v"]
        marg["poses"][p["name"]] = {
            "pixels": int(len(pm["j"])),
            "pixels_per_element_min_max": [int(np.bincount(pm["j"]).min()), int(np.bincount(pm["j"]).max())],
            "min_element_border_margin_elements": float(pm["margin"].min()),
            "min_occluder_edge_margin_half_extents": occluder_margin(sc, P) if sc["occluders"] else None,
        }
    (d / "margins.json").write_text(json.dumps(marg, indent=1) + "\n")
    print(f"{name}: T {T.shape}, blocks {labels}, margins {marg['poses']}")


def make_measure(out):
    d = out / "measure"
    d.mkdir(parents=True, exist_ok=True)
    sc = model.load(ROOT / "config/scenes/brewster-crossed-3x3.toml")
    H = sc["poses"][0]["H"]
    rng = np.random.default_rng(20260503)
    y, x = np.mgrid[0:512, 0:512].astype(np.float64)
    smooth = 1.0 + 0.5 * np.sin(x / 37.0 + 0.3) * np.cos(y / 23.0) + 0.25 * np.exp(-((x - 300) ** 2 + (y - 260) ** 2) / 5000.0)
    checker = 0.2 * (((x.astype(int) // 8) + (y.astype(int) // 8)) % 2)
    frame = (smooth + checker + 0.05 * rng.standard_normal((512, 512))).astype(np.float32)
    variance = (1e-4 * (0.5 + rng.random((512, 512))) * (1.0 + frame)).astype(np.float32)
    i, var = model.measure(frame, H, sc["wall"], variance=variance)
    pm = model.pixel_map(H, sc["wall"])
    counts = np.bincount(pm["j"], minlength=1024).astype(np.int64)
    area = np.bincount(pm["j"], weights=pm["a"], minlength=1024)
    element = np.full((512, 512), -1, dtype=np.int32)
    element[pm["y"], pm["x"]] = pm["j"]
    np.save(d / "frame.npy", frame)
    np.save(d / "variance.npy", variance)
    np.save(d / "H.npy", np.asarray(H, dtype=np.float64))
    np.save(d / "i.npy", i)
    np.save(d / "var.npy", var)
    np.save(d / "counts.npy", counts)
    np.save(d / "area.npy", area)
    np.save(d / "element.npy", element)
    print(f"measure: {counts.sum()} pixels, counts {counts.min()}-{counts.max()}, min border margin "
          f"{pm['margin'].min():.2e} elements, i {i.min():.4f}-{i.max():.4f}")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=str(ROOT / "tests/data/rev3"))
    a = ap.parse_args()
    out = Path(a.out)
    model.selfcheck()
    for name, (src, edits, note) in CASES.items():
        make_case(out, name, src, edits, note)
    make_measure(out)
    print(f"numpy {np.__version__}")


if __name__ == "__main__":
    main()
