#!/usr/bin/env python3
"""Write the MODEL.md on-chip polarizer mosaic reference data under tests/data/mosaic/ with model.py.

    python3 validation/mitsuba/make_mosaic.py [--out tests/data/mosaic]

Independent of the Rust crate: model.py is a separate numpy reading of MODEL.md
("On-chip polarizer mosaic (division-of-focal-plane cameras)"). Same conventions as
make_rev3.py:
  <case>/scene.toml    a config/scenes/ file re-written with the listed edits (values are the
                       parsed file's, printed back exactly: Python's float repr round-trips),
  <case>/T.npy         its T (float64, rows x cols, MODEL.md row order: poses, then the pose's
                       blocks; a mosaic pose's blocks are theta_k = 0, 45, 90, 135),
  <case>/margins.json  the blocks, the shape, and per pose (per mosaic cell under "pixels")
                       pixel counts, the closest any pixel's wall point comes to an element
                       border and any scene->wall segment to an occluder's edge.
Runs model.selfcheck() and model.selfcheck_mosaic() first, and checks each case's own
invariants (see CHECKS below) before writing.
"""
from __future__ import annotations

import argparse
import copy
import json
import math
import sys
import tomllib
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import model  # noqa: E402
from make_rev3 import occluder_margin  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
SCENES = ROOT / "config/scenes"


def _mosaic(pose, sensor_deg, extinction=None, layout=None):
    pose = {k: v for k, v in pose.items() if k != "polarizer_deg"}
    pose["analyzer"] = "mosaic"
    pose["sensor_deg"] = float(sensor_deg)
    if extinction is not None:
        pose["extinction"] = float(extinction)
    if layout is not None:
        pose["layout"] = layout
    return pose


def _load(name):
    with open(SCENES / name, "rb") as f:
        return tomllib.load(f)


def case_brewster_mosaic():
    raw = _load("brewster-multi-3x3.toml")
    raw["pose"] = [_mosaic(p, 0.0) for p in raw["pose"]]
    return raw, "brewster-multi-3x3.toml", (
        "poses B and C, each analyzer = \"mosaic\", sensor_deg = 0, ideal (no extinction); "
        "uniform rows (wall supersample 1); kd = 0")


def case_brewster_e300_pixels():
    raw = _load("brewster-multi-3x3.toml")
    raw["pose"] = [_mosaic(p, 10.0, 300.0) for p in raw["pose"]]
    raw["wall"]["sampling"] = "pixels"
    return raw, "brewster-multi-3x3.toml", (
        "poses B and C, mosaic, sensor_deg = 10, extinction = 300; sampling = \"pixels\" "
        "(each block over its own 2x2 sub-lattice of pixels)")


def case_occluder_kd_pixels():
    raw = _load("occluder-multi-3x3.toml")
    raw["pose"] = [_mosaic(p, -20.0, 100.0) for p in raw["pose"]]
    raw["wall"]["kd"] = 0.1
    raw["wall"]["diffuse"] = "fresnel"
    raw["wall"]["sampling"] = "pixels"
    raw["polarizer"] = {"model": "transmitting"}
    return raw, "occluder-multi-3x3.toml", (
        "poses B and C, occluder, mosaic, sensor_deg = -20, extinction = 100, kd = 0.1 "
        "(fresnel diffuse, so the 1/E term has a diffuse part), [polarizer] model = "
        "\"transmitting\", sampling = \"pixels\"")


def case_mixed():
    a = _load("brewster-crossed-3x3.toml")
    b = _load("brewster-multi-3x3.toml")
    raw = copy.deepcopy(a)
    pa = dict(a["pose"][0])
    pa["polarizer_deg"] = [0.0, 90.0]
    pb = _mosaic(b["pose"][0], 30.0, 50.0, layout="polarsens")
    raw["pose"] = [pa, pb]
    raw["wall"]["supersample"] = 2
    return raw, "brewster-crossed-3x3.toml (pose A) + brewster-multi-3x3.toml (pose B)", (
        "pose A a sheet at polarizer_deg = [0, 90], pose B a mosaic (sensor_deg = 30, "
        "extinction = 50, layout = \"polarsens\" written out); uniform rows, wall supersample 2: "
        "6 blocks A0, A90, B0, B45, B90, B135")


def case_lambert_pixels():
    raw = _load("brewster-crossed-3x3.toml")
    raw["pose"] = [_mosaic(raw["pose"][0], 45.0, 30.0)]
    raw["wall"]["kd"] = 0.2
    raw["wall"]["diffuse"] = "lambert"
    raw["wall"]["sampling"] = "pixels"
    raw["scene"]["supersample"] = 2
    return raw, "brewster-crossed-3x3.toml", (
        "pose A, mosaic, sensor_deg = 45, extinction = 30, kd = 0.2 with diffuse = \"lambert\" "
        "(P_diff = 1/2 + 1/(2E)), scene supersample 2, sampling = \"pixels\"")


CASES = {
    "brewster-mosaic-3x3": case_brewster_mosaic,
    "brewster-mosaic-3x3-e300-pixels": case_brewster_e300_pixels,
    "occluder-mosaic-3x3-kd-pixels": case_occluder_kd_pixels,
    "brewster-mixed-sheet-mosaic-3x3": case_mixed,
    "brewster-mosaic-3x3-lambert-e30-pixels": case_lambert_pixels,
}


# ------------------------------------------------------------------ TOML out
def _val(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        assert math.isfinite(v)
        r = repr(v)
        return r if ("." in r or "e" in r) else r + ".0"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_val(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_val(x)}" for k, x in v.items()) + " }"
    raise TypeError(type(v))


POSE_ORDER = ["name", "camera", "polarizer_deg", "analyzer", "sensor_deg", "extinction", "layout",
              "homography", "region"]


def dump_scene(raw, header):
    out = ["# " + line for line in header.splitlines()]
    for sec in ("wall", "polarizer", "scene"):
        if sec in raw:
            out += ["", f"[{sec}]"] + [f"{k} = {_val(v)}" for k, v in raw[sec].items()]
    for p in raw["pose"]:
        keys = [k for k in POSE_ORDER if k in p] + [k for k in p if k not in POSE_ORDER]
        out += ["", "[[pose]]"] + [f"{k} = {_val(p[k])}" for k in keys]
    for oc in raw.get("occluder", []):
        out += ["", "[[occluder]]"] + [f"{k} = {_val(v)}" for k, v in oc.items()]
    return "\n".join(out) + "\n"


# ------------------------------------------------------------------ checks
def check_case(name, sc, T, labels):
    """Invariants of each case, asserted before writing."""
    J = sc["wall"]["grid"][0] * sc["wall"]["grid"][1]
    assert T.shape == (J * len(labels), sc["scene"]["grid"][0] * sc["scene"]["grid"][1])
    assert np.all(np.isfinite(T)) and np.all(T >= 0)
    res = {}
    if name == "brewster-mosaic-3x3":
        # ideal mosaic at sensor_deg 0, uniform rows == the sheet at [0, 45, 90, 135]
        sheet = copy.deepcopy(sc)
        for p in sheet["poses"]:
            p.update(analyzer=None, deg=[0.0, 45.0, 90.0, 135.0])
        Ts, ls = model.transport(sheet, None)
        assert [l[1] for l in ls] == [l[2] for l in labels]
        err = float(np.abs(Ts - T).max() / np.abs(T).max())
        assert err <= 1e-12, err
        res["vs_sheet_0_45_90_135_max_rel"] = err
    if sc["sampling"] == "pixels":
        # the four cells' element weights add up to the full frame's
        for p in sc["poses"]:
            if p["analyzer"] != "mosaic":
                continue
            full = model.pixel_map(p["H"], sc["wall"])
            n = sum(len(model.cell_pixel_map(p["H"], sc["wall"], c)["j"])
                    for c in model.LAYOUTS[p["layout"]].values())
            assert n == len(full["j"])
    if name == "brewster-mixed-sheet-mosaic-3x3":
        # pose B's block at E = 50 lies between the ideal block and the E = 1 (unpolarized) one:
        # T(E) = T_ideal + (T_unpol - T_ideal)/E exactly (linear in 1/E)
        ideal = copy.deepcopy(sc); ideal["poses"][1]["E"] = None
        unpol = copy.deepcopy(sc); unpol["poses"][1]["E"] = 1.0
        Ti, _ = model.transport(ideal, None)
        Tu, _ = model.transport(unpol, None)
        err = float(np.abs(Ti + (Tu - Ti) / 50.0 - T).max() / np.abs(T).max())
        assert err <= 1e-12, err
        res["linear_in_1/E_max_rel"] = err
    return res


def margins(sc, labels, note, T):
    marg = {"blocks": [], "shape": list(T.shape), "sampling": sc["sampling"], "note": note,
            "poses": {}}
    for p in sc["poses"]:
        for b in model.pose_blocks(p):
            marg["blocks"].append({
                "pose": p["name"],
                "analyzer": p["analyzer"] or ("sheet" if b["psi"] is not None else None),
                "theta_deg": b["label"][2] if p["analyzer"] == "mosaic" else None,
                "psi_deg_from_crossed": None if b["psi"] is None else math.degrees(b["psi"]),
                "extinction": b["E"],
                "pixel_cell_y%2_x%2": list(b["cell"]) if (b["cell"] and sc["sampling"] == "pixels") else None,
            })
    w = sc["wall"]
    for p in sc["poses"]:
        rec = {}
        if sc["sampling"] == "pixels" and p["H"] is not None:
            cells = ([(th, c) for th, c in sorted(model.LAYOUTS[p["layout"]].items())]
                     if p["analyzer"] == "mosaic" else [(None, None)])
            P_all = []
            for th, c in cells:
                pm = model.cell_pixel_map(p["H"], w, c)
                cnt = np.bincount(pm["j"], minlength=w["grid"][0] * w["grid"][1])
                rec["all" if th is None else f"theta {th:g}"] = {
                    "cell_y%2_x%2": None if c is None else list(c),
                    "pixels": int(len(pm["j"])),
                    "pixels_per_element_min_max": [int(cnt.min()), int(cnt.max())],
                    "min_element_border_margin_elements": float(pm["margin"].min()),
                }
                P_all.append(w["c"] + pm["u"][:, None] * w["u"] + pm["v"][:, None] * w["v"])
            P = np.vstack(P_all)
        else:
            P = model.samples(w).reshape(-1, 3)
            rec["uniform_wall_points"] = int(len(P))
        rec["min_occluder_edge_margin_half_extents"] = occluder_margin(sc, P) if sc["occluders"] else None
        marg["poses"][p["name"]] = rec
    return marg


def make_case(out, name, fn):
    raw, src, note = fn()
    d = out / name
    d.mkdir(parents=True, exist_ok=True)
    header = (f"MODEL.md on-chip polarizer mosaic reference case '{name}'\n"
              f"(validation/mitsuba/make_mosaic.py) from config/scenes/{src}:\n{note}.")
    (d / "scene.toml").write_text(dump_scene(raw, header))
    sc = model.load(d / "scene.toml")
    T, labels = model.transport(sc, None)
    T = np.ascontiguousarray(T, dtype=np.float64)
    chk = check_case(name, sc, T, labels)
    np.save(d / "T.npy", T)
    marg = margins(sc, labels, note, T)
    (d / "margins.json").write_text(json.dumps(marg, indent=1) + "\n")
    size = (d / "T.npy").stat().st_size
    assert size < 2_000_000, (name, size)
    print(f"{name}: T {T.shape} ({size} B), blocks {labels}, checks {chk}")
    for pn, rec in marg["poses"].items():
        print(f"   pose {pn}: {json.dumps(rec)}")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=str(ROOT / "tests/data/mosaic"))
    a = ap.parse_args()
    out = Path(a.out)
    model.selfcheck()
    model.selfcheck_mosaic()
    for name, fn in CASES.items():
        make_case(out, name, fn)
    print(f"numpy {np.__version__}, Python {sys.version.split()[0]}")


if __name__ == "__main__":
    main()
