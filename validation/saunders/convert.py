#!/usr/bin/env python3
"""Brings Saunders et al.'s chair photo into polnlos (issue 37, item 7).

Saunders, Murray-Bruce, Goyal, "Computational periscopy with an ordinary
digital camera", Nature 565, 472-475 (2019); data from their public
repository (Computational-Periscopy/Ordinary-Camera, Data/TestPosChair).

Writes, from ../shared/realdata/saunders-chair (or --data):
  config/photos/saunders-chair.toml   the geometry as a polnlos scene file
  tests/data/saunders-chair/measurement.npy   15876 x 3 (R, G, B), one row per row of T
and copies the README and the originals beside them.

Orientation (read from the authors' simulate_A.m / fig_S9.m; a flipped photo
still correlates 0.86 with the right one, so it is written out here):
  photo[r, c]: wall x = FOV_LL.x + FOV.x (v[c] + 1)/2, z = FOV_LL.z + FOV.z (v[125 - r] + 1)/2
               (row 0 at the top, as a photo).
  truth[r, c]: monitor block z = Mon_zdiscr[r] (top first), x = Mon_xdiscr[35 - c]
               (column 0 at the left of a viewer facing the monitor, who has +x on their left).
polnlos orders rows v-outer, u-inner (MODEL.md "Problem"). The wall's u is +x
and its normal -y, so v = n x u = +z: polnlos's wall row 0 is the bottom of the
photo. The monitor's u is -x and its normal +y, so v = +z again: its row 0 is
the bottom block row. Both arrays are therefore flipped upside down here.
"""
import argparse
import json
import pathlib
import shutil

import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
ROOT = HERE.parent.parent


def vec(v):
    return "[" + ", ".join(f"{x:.12g}" for x in v) + "]"


def scene_toml(g):
    d = g["D"]
    ll_x, ll_z = g["FOV_LLCorner_xz"]
    fov_x, fov_z = g["FOV_size_xz"]
    n = len(g["wall_vec"])
    # 126 points from LL to LL + FOV inclusive: elements of pitch FOV/(n-1)
    # centred on them.
    pitch_x, pitch_z = fov_x / (n - 1), fov_z / (n - 1)
    mon = g["monitor"]
    rows, cols = mon["NumBlocks_rows_cols"]
    xd, zd = mon["Mon_xdiscr"], mon["Mon_zdiscr"]
    bx, bz = mon["IlluminationBlock_Size_xz"]
    px, pz = xd[1] - xd[0], zd[0] - zd[1]
    # The authors sample block (r, mc) at Mon_xdiscr[mc] - i bx/2 and
    # Mon_zdiscr[r] - j bz/2 (i, j in 0, 1): its centre is a quarter block
    # below and left of the listed corner. Blocks repeat at the pitch (36
    # monitor pixels) and light 35 of them: the element is the pitch.
    cx = 0.5 * (xd[0] + xd[-1]) - bx / 4
    cz = 0.5 * (zd[0] + zd[-1]) - bz / 4
    lines = [
        "# Saunders et al. (Nature 2019) chair photo: a matte wall 1.03 m from a",
        "# monitor, a chair between them (validation/saunders/convert.py wrote this",
        "# from the authors' geometry; docs/realphoto.md says how).",
        "# Frame: metres; monitor plane y = 0 facing +y, wall plane y = D facing -y, z up.",
        "",
        "[wall]",
        f"center = {vec([ll_x + fov_x / 2, d, ll_z + fov_z / 2])}",
        "normal = [0.0, -1.0, 0.0]",
        "u_axis = [1.0, 0.0, 0.0]",
        f"size = {vec([pitch_x * n, pitch_z * n])}",
        f"grid = [{n}, {n}]",
        "supersample = 1",
        "roughness = 1.0",
        "ior = 1.5",
        "ks = 0.0",
        "kd = 1.0",
        'diffuse = "lambert"',
        'sampling = "uniform"',
        "",
        "[scene]",
        f"center = {vec([cx, 0.0, cz])}",
        "normal = [0.0, 1.0, 0.0]",
        "u_axis = [-1.0, 0.0, 0.0]",
        f"size = {vec([px * cols, pz * rows])}",
        f"grid = [{cols}, {rows}]",
        "supersample = 2",
        'emitter = "lambertian"',
        "# The monitor's emission falls as cos^18 vertically and cos horizontally",
        "# (the authors' viewAngleCorrection), on top of the Lambertian cosine.",
        "lobe = [1.0, 18.0]",
        "",
        "[[pose]]",
        'name = "photo"',
        f"camera = {vec([ll_x + fov_x / 2, 0.3, ll_z + fov_z / 2])}",
        "polarizer_deg = []",
    ]
    occ = g["occluder"]
    lines += ["", "# The chair: seat, back and legs as the authors' quads (their estimated position)."]
    for q in occ["chair_quads_corners"]:
        q = np.array(q, dtype=float)
        c = q.mean(axis=0)
        hu = (q[1] - q[0]) / 2
        hv = (q[3] - q[0]) / 2
        lines += ["[[occluder]]", f"rect = {{ center = {vec(c)}, half_u = {vec(hu)}, half_v = {vec(hv)} }}"]
    return "\n".join(lines) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(ROOT.parent / "shared/realdata/saunders-chair"))
    a = ap.parse_args()
    src = pathlib.Path(a.data)
    g = json.loads((src / "geometry.json").read_text())
    (ROOT / "config/photos/saunders-chair.toml").write_text(scene_toml(g))
    out = ROOT / "tests/data/saunders-chair"
    out.mkdir(parents=True, exist_ok=True)
    photo = np.load(src / "measurement_rgb.npy")
    np.save(out / "measurement.npy", np.ascontiguousarray(photo[::-1].reshape(-1, 3)))
    for f in ["README.md", "geometry.json", "measurement_rgb.npy", "truth_rgb.npy", "truth_rgb_x8.png"]:
        shutil.copyfile(src / f, out / f)
        (out / f).chmod(0o644)


if __name__ == "__main__":
    main()
