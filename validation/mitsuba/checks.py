#!/usr/bin/env python3
"""Set-up checks of render.py against MODEL.md (see README.md).

    python3 validation/mitsuba/checks.py probe SCENE.toml [--iu 1 --iv 6] [--spp 4096]
        One lit scene element (iu, iv): the rendered wall image must correlate best
        with column iv*nu+iu of model.py's T (bitmap orientation), with gain ~1.

    python3 validation/mitsuba/checks.py sweep SCENE.toml [--pose A] [--spp 1048576]
        A small uniform source (1 cm square) at the scene centre, the pose's sheet at
        psi = -10..10 deg, S0 along the camera -> c0 ray. The minimum must be at psi = 0
        (MODEL.md's crossed axis q(0)); prints the parabola-fit minimum and the same
        curve from model.py.
"""
from __future__ import annotations

import argparse
import copy
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import model  # noqa: E402
import render  # noqa: E402


def probe(a):
    sc = render.load_scene_file(a.scene)
    nu, nv = sc["scene"]["grid"]
    truth = np.zeros((nv, nu))
    truth[a.iv, a.iu] = 1.0
    i, sig, info, secs, _ = render.render(sc, truth, a.spp, 4, a.variant, 7, log=lambda *_: None)
    T, labels = model.build(model.load(a.scene))
    k0 = a.iv * nu + a.iu
    corr = np.array([T[:, k] @ i / np.linalg.norm(T[:, k]) / np.linalg.norm(i) for k in range(nu * nv)])
    order = np.argsort(corr)[::-1]
    p = T[:, k0]
    gain = p @ i / (p @ p)
    resid = np.sqrt(np.mean((i - p) ** 2) / np.mean(i ** 2))
    noise = np.sqrt(np.mean(sig ** 2) / np.mean(i ** 2))
    print(f"probe (iu, iv) = ({a.iu}, {a.iv}), blocks {[(b['pose'], b['polarizer_deg']) for b in info]}")
    print("  best-correlated columns of T: " + ", ".join(
        f"(iu {k % nu}, iv {k // nu}) {corr[k]:.6f}" for k in order[:4]))
    # the candidate orientations a wrong bitmap mapping would give
    for name, (u, v) in {"v flipped": (a.iu, nv - 1 - a.iv), "u flipped": (nu - 1 - a.iu, a.iv),
                         "transposed": (a.iv, a.iu)}.items():
        if 0 <= u < nu and 0 <= v < nv and (u, v) != (a.iu, a.iv):
            print(f"  {name:>10} column (iu {u}, iv {v}): correlation {corr[v * nu + u]:.6f}")
    print(f"  gain vs T[:, {k0}] = {gain:.5f}, residual {100 * resid:.3f} %, noise {100 * noise:.3f} %")
    ok = order[0] == k0
    print("  PASS" if ok else "  FAIL")
    return 0 if ok else 1


def sweep(a):
    sc = render.load_scene_file(a.scene)
    pose = next(p for p in sc["poses"] if p["name"] == a.pose)
    small = copy.deepcopy(sc)
    small["scene"]["size"] = (a.source, a.source)
    small["scene"]["grid"] = (1, 1)
    truth = np.ones((1, 1))
    c0 = sc["wall"]["c"]
    pts_sheet = render.wall_points(sc["wall"])   # the sheet is sized as for the full wall
    mi = render.setup_mitsuba(a.variant)
    psis = np.arange(-a.range, a.range + 1e-9, a.step)
    S, E = [], []
    msc = model.load(a.scene)
    msc["scene"]["size"] = (a.source, a.source)
    msc["scene"]["grid"] = (1, 1)
    msc["scene"]["m"] = 64      # the leak is 2nd order in the source offset: midpoint error 1/m^2
    msc["wall"]["grid"] = (1, 1)
    msc["wall"]["size"] = (1e-9, 1e-9)     # one wall point: c0
    msc["wall"]["m"] = 1
    mpose = next(p for p in msc["poses"] if p["name"] == a.pose)
    for k, psi in enumerate(psis):
        scene, _ = render.build_scene(mi, small, truth, pose, math.radians(psi), pts_sheet)
        means = [render.render_points(mi, scene, pose["o"], c0[None, :], a.spp // 8, 1000 + 17 * k + b)[0]
                 for b in range(8)]
        S.append(np.mean(means))
        E.append(np.std(means, ddof=1) / math.sqrt(8))
    S, E = np.array(S), np.array(E)
    M = np.array([model.block(msc, mpose, math.radians(p))[0, 0] for p in psis])
    Mfine = lambda p: model.block(msc, mpose, math.radians(p))[0, 0]

    def vertex(y):
        c = np.polyfit(psis, y, 2)
        return -c[1] / (2 * c[0])

    print(f"sweep pose {a.pose}: source {a.source*100:.1f} cm square at s0, ray camera -> c0, spp {a.spp}")
    print("   psi deg      S0 render        stderr      S0 model   render/model")
    for p, s, e, m in zip(psis, S, E, M):
        print(f"  {p:7.2f}  {s:13.6e}  {e:11.3e}  {m:13.6e}   {s / m:.5f}")
    i_min = int(np.argmin(S))
    # minimum of the model curve on a fine grid
    fine = np.linspace(-1, 1, 401)
    mf = np.array([Mfine(p) for p in fine])
    print(f"  sampled minimum at psi = {psis[i_min]:.2f} deg; parabola vertex render {vertex(S):+.4f} deg,"
          f" model {vertex(M):+.4f} deg (fine-grid model minimum {fine[np.argmin(mf)]:+.4f} deg)")
    # vertex uncertainty by resampling the noise
    rng = np.random.default_rng(0)
    vs = [vertex(S + rng.normal(0, E)) for _ in range(400)]
    print(f"  render vertex noise (1 sigma): {np.std(vs):.4f} deg")
    gain = (M @ S) / (M @ M)
    print(f"  gain render/model over the sweep {gain:.5f}, max |S/M - 1| {np.max(np.abs(S / M - 1)) * 100:.3f} %,"
          f" max |S - M|/stderr {np.max(np.abs(S - M) / E):.2f}")
    return 0


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("probe")
    p.add_argument("scene")
    p.add_argument("--iu", type=int, default=1)
    p.add_argument("--iv", type=int, default=6)
    p.add_argument("--spp", type=int, default=4096)
    p.add_argument("--variant", default="llvm_ad_mono_polarized")
    s = sub.add_parser("sweep")
    s.add_argument("scene")
    s.add_argument("--pose", default="A")
    s.add_argument("--spp", type=int, default=1 << 22)
    s.add_argument("--range", type=float, default=10.0)
    s.add_argument("--step", type=float, default=1.0)
    s.add_argument("--source", type=float, default=0.01, help="source square side, metres")
    s.add_argument("--variant", default="llvm_ad_mono_polarized")
    a = ap.parse_args()
    sys.exit(probe(a) if a.cmd == "probe" else sweep(a))


if __name__ == "__main__":
    main()
