#!/usr/bin/env python3
"""Render a polnlos scene file with Mitsuba 3 (independent renderer check).

    python3 validation/mitsuba/render.py SCENE.toml (--truth TRUTH.npy | --pattern letter) \
        --out DIR [--spp 32768] [--batches 16] [--variant llvm_ad_mono_polarized] [--seed N]

Writes to DIR:
  i.npy       float64 measurement vector in T's row order (blocks in pose order then
              polarizer-angle order, a pose without polarizer is one block; inside a
              block wall elements row-major, index iv*nu + iu). Element value = mean
              over the element's m x m wall sub-sample points of the S0 (Mueller [0,0],
              the light is unpolarized) of the radiance arriving at the camera centre
              along the ray camera -> sub-sample point.
  sigma.npy   float64 standard error of i: std(ddof=1)/sqrt(batches) of the
              independent batch means.
  truth.npy   float64 (nv, nu) scene radiance used (row iv, column iu).
  render.json settings, timings, Mitsuba version, block list.

With --frames WIDTH HEIGHT (every pose needs a homography; --spp is per pixel) it writes
instead, per block k in T's order:
  frame-<k>.npy        float32 (HEIGHT, WIDTH) camera frame, pixel (x, y) at [y, x]: the mean
                       S0 over spp rays from the camera centre to the wall points
                       H^-1(x + jx, y + jy), jitter uniform in [-1/2, 1/2)^2; samples off the
                       wall (grown by --wall-margin, default 1 cm) count 0.
  frame-sigma-<k>.npy  float32 per-pixel standard error from the batch means;
and truth.npy, render.json (with each element's noise measured through model.py's measure).

Mitsuba scene (MODEL.md geometry, see README.md for the checks):
  * wall: `rectangle` placed as the wall plane, `pplastic` (ggx, alpha = roughness,
    int_ior = ior, ext_ior = 1.0, diffuse_reflectance = kd, specular_reflectance = ks);
  * hidden scene: `rectangle` placed as the scene plane (its normal, the emitting
    side, as in the file: towards the wall), black BSDF, `area` emitter whose radiance
    is a `bitmap` of the truth (raw, nearest, clamp), bitmap row = v index;
  * occluders: black (diffuse reflectance 0), non-emitting rectangles / spheres;
  * polarizer (per block with an angle): a square `rectangle` with the `polarizer`
    BSDF, SHEET_DIST in front of the camera, normal n_p = normalize(c0 - camera),
    U axis = q(psi) (transmission), V axis = n_p x q(psi) (Mitsuba's absorbing axis);
  * integrator `volpath` (max_depth 4), called directly with rays from the camera
    centre to every wall sample point (no sensor).
`[polarizer] model` and `[wall] diffuse` are accepted and ignored: this is physics.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

DEFAULT_LLVM = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"
SHEET_DIST = 0.01          # metres from the camera centre to the polarizer sheet
SHEET_MARGIN = 1.25        # sheet half-size = margin * largest ray offset on it
MAX_LANES = 1 << 21        # rays per kernel launch (memory bound)


# ----------------------------------------------------------------- scene file
def _unit(x, key):
    x = np.asarray(x, dtype=float)
    if x.shape != (3,):
        raise ValueError(f"{key}: expected 3 numbers")
    nrm = np.linalg.norm(x)
    if not nrm > 0:
        raise ValueError(f"{key}: zero vector")
    return x / nrm


def _plane(d, key):
    for k in ("center", "normal", "u_axis", "size", "grid"):
        if k not in d:
            raise ValueError(f"{key}.{k}: missing")
    n = _unit(d["normal"], f"{key}.normal")
    u = np.asarray(d["u_axis"], dtype=float)
    u = _unit(u - np.dot(u, n) * n, f"{key}.u_axis")
    v = np.cross(n, u)
    nu, nv = int(d["grid"][0]), int(d["grid"][1])
    m = int(d.get("supersample", 1))
    if nu < 1 or nv < 1:
        raise ValueError(f"{key}.grid: must be >= 1")
    if m < 1:
        raise ValueError(f"{key}.supersample: must be >= 1")
    return dict(c=np.asarray(d["center"], dtype=float), n=n, u=u, v=v,
                size=(float(d["size"][0]), float(d["size"][1])), grid=(nu, nv), m=m)


def load_scene_file(path):
    with open(path, "rb") as f:
        raw = tomllib.load(f)
    if "wall" not in raw:
        raise ValueError("wall: missing")
    if "scene" not in raw:
        raise ValueError("scene: missing")
    w, s = raw["wall"], raw["scene"]
    sc = dict(wall=_plane(w, "wall"), scene=_plane(s, "scene"))
    if "roughness" not in w:
        raise ValueError("wall.roughness: missing")
    if "ior" not in w:
        raise ValueError("wall.ior: missing")
    sc["alpha"] = float(w["roughness"])
    sc["ior"] = float(w["ior"])
    sc["ks"] = float(w.get("ks", 1.0))
    sc["kd"] = float(w.get("kd", 0.0))
    if not 0 < sc["alpha"] <= 1:
        raise ValueError("wall.roughness: outside (0, 1]")
    if not sc["ior"] > 1:
        raise ValueError("wall.ior: must be > 1")
    emitter = s.get("emitter", "lambertian")
    if emitter != "lambertian":
        # Mitsuba's area emitter is a constant-radiance (lambertian) source.
        raise ValueError(f"scene.emitter: {emitter!r} not supported by the renderer (lambertian only)")
    if "polarization" in s:
        raise ValueError("scene.polarization: polarized scenes are not supported by the renderer")
    poses = raw.get("pose", [])
    if not poses:
        raise ValueError("pose: at least one is required")
    sc["poses"] = []
    for k, p in enumerate(poses):
        if "camera" not in p:
            raise ValueError(f"pose[{k}].camera: missing")
        H = None
        if "homography" in p:
            H = np.asarray(p["homography"], dtype=float)
            if H.shape != (3, 3) or not np.all(np.isfinite(H)) or abs(np.linalg.det(H)) == 0:
                raise ValueError(f"pose[{k}].homography: not an invertible 3x3 matrix")
        sc["poses"].append(dict(name=str(p.get("name", str(k))),
                                o=np.asarray(p["camera"], dtype=float),
                                deg=[float(a) for a in p.get("polarizer_deg", [])],
                                H=H))
    sc["occluders"] = []
    for k, oc in enumerate(raw.get("occluder", [])):
        if "rect" in oc:
            r = oc["rect"]
            sc["occluders"].append(dict(kind="rect", c=np.asarray(r["center"], float),
                                        hu=np.asarray(r["half_u"], float),
                                        hv=np.asarray(r["half_v"], float)))
        elif "sphere" in oc:
            r = oc["sphere"]
            sc["occluders"].append(dict(kind="sphere", c=np.asarray(r["center"], float),
                                        r=float(r["radius"])))
        else:
            raise ValueError(f"occluder[{k}]: neither rect nor sphere")
    # [polarizer] model and [wall] diffuse are accepted and ignored (physics decides).
    return sc


def wall_points(pl):
    """Wall sub-sample points, (nv*nu*m*m, 3): element-major (iv*nu+iu), then sub-samples."""
    nu, nv = pl["grid"]
    su, sv = pl["size"]
    m = pl["m"]
    pts = np.empty((nv, nu, m, m, 3))
    for iv in range(nv):
        for iu in range(nu):
            for b in range(m):
                for a in range(m):
                    x = ((iu + (a + 0.5) / m) / nu - 0.5) * su
                    y = ((iv + (b + 0.5) / m) / nv - 0.5) * sv
                    pts[iv, iu, b, a] = pl["c"] + x * pl["u"] + y * pl["v"]
    return pts.reshape(-1, 3)


def letter_pattern(nu, nv):
    """polnlos's letter F: fraction of 4x4 sub-points inside the F, shape (nv, nu)."""
    out = np.zeros((nv, nu))
    for iv in range(nv):
        for iu in range(nu):
            hits = 0
            for b in range(4):
                for a in range(4):
                    x = (iu + (a + 0.5) / 4) / nu
                    y = (iv + (b + 0.5) / 4) / nv
                    stem = 0.25 <= x < 0.42 and 0.12 <= y < 0.88
                    top = 0.25 <= x < 0.78 and 0.12 <= y < 0.28
                    mid = 0.25 <= x < 0.66 and 0.44 <= y < 0.58
                    hits += stem or top or mid
            out[iv, iu] = hits / 16
    return out


def crossed_axis(sc, o, psi_rad):
    """(n_p, q(psi)) per MODEL.md 'The crossed polarizer of a pose'."""
    c0, s0 = sc["wall"]["c"], sc["scene"]["c"]
    n_p = (c0 - o) / np.linalg.norm(c0 - o)
    wi0 = (s0 - c0) / np.linalg.norm(s0 - c0)
    wo0 = (o - c0) / np.linalg.norm(o - c0)
    es0 = np.cross(wi0, wo0)
    if np.linalg.norm(es0) < 1e-12:
        raise ValueError("pose.camera: crossed axis undefined (w_i0 parallel to w_o0)")
    es0 /= np.linalg.norm(es0)
    q0 = np.cross(es0, n_p)
    q0 /= np.linalg.norm(q0)
    c, s = math.cos(psi_rad), math.sin(psi_rad)
    q = q0 * c + np.cross(n_p, q0) * s + n_p * np.dot(n_p, q0) * (1 - c)
    return n_p, q / np.linalg.norm(q)


# ------------------------------------------------------------------- mitsuba
def setup_mitsuba(variant):
    if variant.startswith("llvm") and "DRJIT_LIBLLVM_PATH" not in os.environ and os.path.exists(DEFAULT_LLVM):
        os.environ["DRJIT_LIBLLVM_PATH"] = DEFAULT_LLVM
    import mitsuba as mi
    if variant not in mi.variants():
        raise SystemExit(f"variant {variant!r} not in this Mitsuba build: {mi.variants()}")
    if "polarized" not in variant or "mono" not in variant:
        raise SystemExit("the renderer needs a *_mono_polarized variant")
    if variant.startswith("scalar"):
        raise SystemExit("scalar variants would need a Python loop per ray; use llvm_ad_/cuda_ad_mono_polarized")
    mi.set_variant(variant)
    return mi


def _frame_matrix(c, ex, ey, ez):
    """4x4 to_world with columns ex, ey, ez, c (the rectangle spans local [-1,1]^2)."""
    M = np.eye(4)
    M[:3, 0], M[:3, 1], M[:3, 2], M[:3, 3] = ex, ey, ez, c
    return M.tolist()


def plane_rectangle(mi, pl):
    hu, hv = pl["size"][0] / 2, pl["size"][1] / 2
    return mi.ScalarTransform4f(_frame_matrix(pl["c"], hu * pl["u"], hv * pl["v"], pl["n"]))


def black(mi):
    return {"type": "diffuse", "reflectance": {"type": "uniform", "value": 0.0}}


def sheet_geometry(sc, o, n_p, q, pts):
    """Centre and half-size of the polarizer square covering every camera->wall ray."""
    a = np.cross(n_p, q)
    centre = o + SHEET_DIST * n_p
    d = pts - o
    t = SHEET_DIST / (d @ n_p)
    if np.any(t <= 0):
        raise ValueError("pose.camera: wall point behind the polarizer plane")
    hit = o + t[:, None] * d - centre
    half = SHEET_MARGIN * max(np.max(np.abs(hit @ q)), np.max(np.abs(hit @ a)))
    return centre, half, a


def build_scene(mi, sc, truth, pose=None, psi_rad=None, pts=None, max_depth=4,
                flip_rows=False):
    wall, scene = sc["wall"], sc["scene"]
    d = {"type": "scene"}
    d["integrator"] = {"type": "volpath", "max_depth": max_depth}
    d["wall"] = {
        "type": "rectangle",
        "to_world": plane_rectangle(mi, wall),
        "bsdf": {
            "type": "pplastic",
            "distribution": "ggx",
            "alpha": sc["alpha"],
            "int_ior": sc["ior"],
            "ext_ior": 1.0,
            "diffuse_reflectance": {"type": "uniform", "value": sc["kd"]},
            "specular_reflectance": {"type": "uniform", "value": sc["ks"]},
        },
    }
    tex = np.ascontiguousarray((truth[::-1] if flip_rows else truth)[:, :, None], dtype=np.float32)
    d["hidden"] = {
        "type": "rectangle",
        "to_world": plane_rectangle(mi, scene),
        "bsdf": black(mi),
        "emitter": {
            "type": "area",
            "radiance": {
                "type": "bitmap",
                "data": mi.TensorXf(tex),
                "raw": True,
                "filter_type": "nearest",
                "wrap_mode": "clamp",
            },
        },
    }
    for k, oc in enumerate(sc["occluders"]):
        if oc["kind"] == "rect":
            nrm = np.cross(oc["hu"], oc["hv"])
            if not np.linalg.norm(nrm) > 0:
                raise ValueError(f"occluder[{k}].rect: degenerate")
            nrm /= np.linalg.norm(nrm)
            d[f"occluder{k}"] = {
                "type": "rectangle",
                "to_world": mi.ScalarTransform4f(_frame_matrix(oc["c"], oc["hu"], oc["hv"], nrm)),
                "bsdf": black(mi),
            }
        else:
            d[f"occluder{k}"] = {"type": "sphere", "center": oc["c"].tolist(),
                                 "radius": oc["r"], "bsdf": black(mi)}
    sheet = None
    if psi_rad is not None:
        n_p, q = crossed_axis(sc, pose["o"], psi_rad)
        centre, half, a = sheet_geometry(sc, pose["o"], n_p, q, pts)
        # local x (U, dp/du) = q: transmission; local y (V) = n_p x q: Mitsuba's absorbing axis
        d["polarizer"] = {
            "type": "rectangle",
            "to_world": mi.ScalarTransform4f(_frame_matrix(centre, half * q, half * a, n_p)),
            "bsdf": {"type": "polarizer"},
        }
        sheet = dict(centre=centre.tolist(), half_size=half, q=q.tolist(), absorbing_axis=a.tolist(),
                     n_p=n_p.tolist())
    return mi.load_dict(d), sheet


def render_points(mi, scene, o, pts, spp, seed):
    """Mean S0 per point over `spp` samples (float64 numpy, shape (len(pts),))."""
    import drjit as dr
    npts = len(pts)
    integrator = scene.integrator()
    acc = np.zeros(npts)
    per_launch = max(1, MAX_LANES // npts)
    done, launch = 0, 0
    dirs = pts - o
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    D = mi.Vector3f(dirs[:, 0], dirs[:, 1], dirs[:, 2])
    while done < spp:
        k = min(per_launch, spp - done)
        n = k * npts
        idx = dr.arange(mi.UInt32, n) % npts
        d = dr.gather(mi.Vector3f, D, idx)
        ray = mi.RayDifferential3f(mi.Ray3f(mi.Point3f(*[float(x) for x in o]), d))
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(dr.opaque(mi.UInt32, (seed * 7919 + launch) & 0xFFFFFFFF), n)
        spec, valid, _ = integrator.sample(scene, sampler, ray)
        s0 = spec[0, 0] if hasattr(spec, "shape") and len(spec.shape) >= 2 else spec
        v = np.asarray(s0, dtype=np.float64).reshape(-1)
        if v.size != n:
            v = np.asarray(dr.ravel(s0), dtype=np.float64)[:n]
        if not np.all(np.isfinite(v)):
            raise RuntimeError(f"{np.sum(~np.isfinite(v))} non-finite samples")
        acc += v.reshape(k, npts).sum(axis=0)
        done += k
        launch += 1
    return acc / spp


def render(sc, truth, spp, batches, variant, seed, max_depth=4, flip_rows=False, log=print):
    mi = setup_mitsuba(variant)
    pts = wall_points(sc["wall"])
    m2 = sc["wall"]["m"] ** 2
    nel = len(pts) // m2
    spp_b = spp // batches
    spp_pt = max(1, spp_b // m2)  # per sub-sample point per batch: element gets ~spp_b rays
    blocks, info = [], []
    t_all = time.time()
    bi = 0
    for p in sc["poses"]:
        angles = p["deg"] if p["deg"] else [None]
        for deg in angles:
            t0 = time.time()
            psi = None if deg is None else math.radians(deg)
            scene, sheet = build_scene(mi, sc, truth, p, psi, pts, max_depth, flip_rows)
            means = np.empty((batches, nel))
            for b in range(batches):
                bseed = (seed * 1_000_003 + bi * 10_007 + b * 101) & 0x7FFFFFFF
                v = render_points(mi, scene, p["o"], pts, spp_pt, bseed)
                means[b] = v.reshape(nel, m2).mean(axis=1)
            dt = time.time() - t0
            blocks.append(means)
            info.append(dict(pose=p["name"], polarizer_deg=deg, seconds=round(dt, 2), sheet=sheet))
            log(f"block {bi} pose {p['name']} polarizer {deg}: {dt:.1f} s")
            bi += 1
    means = np.concatenate(blocks, axis=1)          # (batches, rows)
    i = means.mean(axis=0)
    sigma = means.std(axis=0, ddof=1) / math.sqrt(batches)
    return i, sigma, info, time.time() - t_all, spp_pt * m2 * batches


def frame_pixels(H, wall, width, height, margin):
    """Pixels of a width x height frame whose square can reach the (extended) wall: the
    integer points of the bounding box of the extended wall's image, grown by one pixel."""
    su, sv = wall["size"][0] / 2 + margin, wall["size"][1] / 2 + margin
    c = np.array([[-su, -sv, 1], [su, -sv, 1], [su, sv, 1], [-su, sv, 1]]) @ H.T
    if not np.all(c[:, 2] > 0):
        raise ValueError("pose.homography: a wall corner maps behind the camera")
    x, y = c[:, 0] / c[:, 2], c[:, 1] / c[:, 2]
    x0, x1 = max(0, math.floor(x.min()) - 1), min(width - 1, math.ceil(x.max()) + 1)
    y0, y1 = max(0, math.floor(y.min()) - 1), min(height - 1, math.ceil(y.max()) + 1)
    X, Y = np.meshgrid(np.arange(x0, x1 + 1), np.arange(y0, y1 + 1))
    return X.ravel(), Y.ravel()


def render_frame_batch(mi, scene, o, H, wall, margin, px, py, spp, seed):
    """Mean S0 per pixel over `spp` jittered samples (float64, shape (len(px),)).

    Sample: (x + jx, y + jy), (jx, jy) uniform in [-1/2, 1/2)^2, mapped by H^-1 to the wall
    plane; a sample on the wall rectangle grown by `margin` on every side is traced along
    camera -> that wall point, any other contributes 0 (dark background)."""
    import drjit as dr
    G = np.linalg.inv(H)
    su, sv = wall["size"][0] / 2 + margin, wall["size"][1] / 2 + margin
    npix = len(px)
    acc = np.zeros(npix)
    rng = np.random.default_rng(seed)
    integrator = scene.integrator()
    per_launch = max(1, MAX_LANES // npix)
    done, launch = 0, 0
    O = mi.Point3f(*[float(t) for t in o])
    while done < spp:
        k = min(per_launch, spp - done)
        jx = rng.random((k, npix)) - 0.5
        jy = rng.random((k, npix)) - 0.5
        X, Y = px[None, :] + jx, py[None, :] + jy
        w = G[2, 0] * X + G[2, 1] * Y + G[2, 2]
        u = (G[0, 0] * X + G[0, 1] * Y + G[0, 2]) / w
        v = (G[1, 0] * X + G[1, 1] * Y + G[1, 2]) / w
        on = (w > 0) & (np.abs(u) <= su) & (np.abs(v) <= sv)
        idx = np.nonzero(on.ravel())[0]
        if idx.size:
            P = wall["c"] + u.ravel()[idx, None] * wall["u"] + v.ravel()[idx, None] * wall["v"]
            d = P - o
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            ray = mi.RayDifferential3f(mi.Ray3f(O, mi.Vector3f(d[:, 0], d[:, 1], d[:, 2])))
            sampler = mi.load_dict({"type": "independent"})
            sampler.seed(dr.opaque(mi.UInt32, (seed * 7919 + launch) & 0xFFFFFFFF), int(idx.size))
            spec, _, _ = integrator.sample(scene, sampler, ray)
            s0 = spec[0, 0] if hasattr(spec, "shape") and len(spec.shape) >= 2 else spec
            val = np.asarray(s0, dtype=np.float64).reshape(-1)
            if val.size != idx.size:
                val = np.asarray(dr.ravel(s0), dtype=np.float64)[:idx.size]
            if not np.all(np.isfinite(val)):
                raise RuntimeError(f"{np.sum(~np.isfinite(val))} non-finite samples")
            acc += np.bincount(idx % npix, weights=val, minlength=npix)
        done += k
        launch += 1
    return acc / spp


def render_frames(sc, truth, width, height, spp, batches, variant, seed, margin=0.01,
                  max_depth=4, log=print):
    """Per block a (height, width) camera frame: mean S0 over `spp` jittered rays per pixel,
    split in `batches` independent batches. Returns (frames, sigmas, batch_frames, info, secs)."""
    mi = setup_mitsuba(variant)
    for p in sc["poses"]:
        if p["H"] is None:
            raise ValueError(f"pose {p['name']}: --frames needs a homography")
    wall = sc["wall"]
    big = dict(sc, wall=dict(wall, size=(wall["size"][0] + 2 * margin, wall["size"][1] + 2 * margin)))
    su, sv = big["wall"]["size"][0] / 2, big["wall"]["size"][1] / 2
    corners = wall["c"] + np.array([[a * su, b * sv] for a in (-1, 1) for b in (-1, 1)]) @ np.stack([wall["u"], wall["v"]])
    spp_b = spp // batches
    frames, sigmas, per_batch, info = [], [], [], []
    t_all = time.time()
    bi = 0
    for p in sc["poses"]:
        px, py = frame_pixels(p["H"], wall, width, height, margin)
        for deg in (p["deg"] or [None]):
            t0 = time.time()
            psi = None if deg is None else math.radians(deg)
            scene, sheet = build_scene(mi, big, truth, p, psi, corners, max_depth)
            means = np.zeros((batches, height, width))
            for b in range(batches):
                bseed = (seed * 1_000_003 + bi * 10_007 + b * 101) & 0x7FFFFFFF
                means[b, py, px] = render_frame_batch(mi, scene, p["o"], p["H"], wall, margin, px, py, spp_b, bseed)
            dt = time.time() - t0
            frames.append(means.mean(axis=0))
            sigmas.append(means.std(axis=0, ddof=1) / math.sqrt(batches))
            per_batch.append(means)
            info.append(dict(pose=p["name"], polarizer_deg=deg, seconds=round(dt, 2), sheet=sheet,
                             traced_pixels=int(len(px))))
            log(f"block {bi} pose {p['name']} polarizer {deg}: {dt:.1f} s ({len(px)} pixels x {spp_b * batches} spp)")
            bi += 1
    return frames, sigmas, per_batch, info, time.time() - t_all, spp_b * batches


def main_frames(a, sc, truth, pattern):
    width, height = a.frames
    frames, sigmas, per_batch, info, secs, spp_eff = render_frames(
        sc, truth, width, height, a.spp, a.batches, a.variant, a.seed, a.wall_margin, a.max_depth)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    for k, (f, s) in enumerate(zip(frames, sigmas)):
        np.save(out / f"frame-{k}.npy", f.astype(np.float32))
        np.save(out / f"frame-sigma-{k}.npy", s.astype(np.float32))
    np.save(out / "truth.npy", truth)
    # diagnostics: each wall element's mean over its pixels (model.py's measure, MODEL.md
    # rev 3) per batch: its standard error measured directly, against sigma propagated
    import mitsuba as mi
    import drjit as dr
    import model
    for k, p in enumerate(b for p in sc["poses"] for b in [p] * max(1, len(p["deg"]))):
        wall = dict(size=sc["wall"]["size"], grid=sc["wall"]["grid"])
        el = np.array([model.measure(m, p["H"], wall)[0] for m in per_batch[k]])
        i = el.mean(axis=0)
        direct = el.std(axis=0, ddof=1) / math.sqrt(a.batches)
        _, var = model.measure(frames[k], p["H"], wall, variance=sigmas[k] ** 2)
        info[k]["element_median_rel_stderr_direct"] = float(np.median(direct / i))
        info[k]["element_median_rel_stderr_propagated"] = float(np.median(np.sqrt(var) / i))
        on = frames[k] > 0
        info[k]["pixel_median_rel_stderr"] = float(np.median(sigmas[k][on] / frames[k][on]))
    meta = dict(
        scene_file=Path(a.scene).name, mode="frames", width=width, height=height,
        spp_per_pixel=spp_eff, spp_requested=a.spp, batches=a.batches, variant=a.variant,
        mitsuba=mi.__version__, drjit=dr.__version__, seed=a.seed,
        integrator=dict(type="volpath", max_depth=a.max_depth), wall_margin_m=a.wall_margin,
        seconds=round(secs, 2), pattern=pattern,
        wall_grid=list(sc["wall"]["grid"]), scene_grid=list(sc["scene"]["grid"]),
        blocks=info,
    )
    with open(out / "render.json", "w") as f:
        json.dump(meta, f, indent=1)
        f.write("\n")
    print(f"{len(frames)} frames in {secs:.1f} s, element median relative stderr "
          + ", ".join(f"{100 * b['element_median_rel_stderr_direct']:.3f} %" for b in info))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene", help="polnlos scene file (TOML)")
    g = ap.add_mutually_exclusive_group(required=True)
    g.add_argument("--truth", help="(nv, nu) .npy scene radiance")
    g.add_argument("--pattern", help="letter | probe:IU,IV | uniform")
    ap.add_argument("--out", required=True)
    ap.add_argument("--spp", type=int, default=32768, help="samples per wall element (total over batches)")
    ap.add_argument("--batches", type=int, default=16)
    ap.add_argument("--variant", default="llvm_ad_mono_polarized")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--max-depth", type=int, default=4)
    ap.add_argument("--frames", nargs=2, type=int, metavar=("WIDTH", "HEIGHT"),
                    help="render camera frames (one per block) through each pose's homography "
                         "instead of per-element values; --spp is then per pixel")
    ap.add_argument("--wall-margin", type=float, default=0.01,
                    help="--frames: metres the Mitsuba wall extends beyond the file's wall on every "
                         "side (a real wall goes on; 0 = dark beyond the file's wall)")
    ap.add_argument("--flip-rows", action="store_true",
                    help="debug only: feed the bitmap upside down (for the orientation probe)")
    a = ap.parse_args(argv)
    if a.batches < 2:
        ap.error("--batches must be >= 2 (the standard error needs a spread)")
    if a.spp < a.batches:
        ap.error("--spp must be >= --batches")

    sc = load_scene_file(a.scene)
    nu, nv = sc["scene"]["grid"]
    if a.truth:
        truth = np.asarray(np.load(a.truth), dtype=np.float64)
        if truth.shape != (nv, nu):
            if truth.size == nu * nv:
                truth = truth.reshape(nv, nu)
            else:
                raise SystemExit(f"truth shape {truth.shape} does not match the scene grid (nv, nu) = {(nv, nu)}")
        pattern = None
    elif a.pattern == "letter":
        truth, pattern = letter_pattern(nu, nv), "letter"
    elif a.pattern == "uniform":
        truth, pattern = np.ones((nv, nu)), "uniform"
    elif a.pattern.startswith("probe:"):
        iu, iv = (int(x) for x in a.pattern[6:].split(","))
        truth = np.zeros((nv, nu))
        truth[iv, iu] = 1.0
        pattern = a.pattern
    else:
        raise SystemExit(f"unknown pattern {a.pattern!r}")
    if np.any(truth < 0) or not np.all(np.isfinite(truth)):
        raise SystemExit("truth must be finite and >= 0")

    if a.frames:
        return main_frames(a, sc, truth, pattern)

    i, sigma, info, secs, spp_eff = render(sc, truth, a.spp, a.batches, a.variant, a.seed,
                                           a.max_depth, a.flip_rows)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    np.save(out / "i.npy", i)
    np.save(out / "sigma.npy", sigma)
    np.save(out / "truth.npy", truth)
    import mitsuba as mi
    import drjit as dr
    rel = sigma / np.where(i > 0, i, np.nan)
    meta = dict(
        scene_file=Path(a.scene).name,
        spp=spp_eff, spp_requested=a.spp, batches=a.batches, variant=a.variant,
        mitsuba=mi.__version__, drjit=dr.__version__, seed=a.seed,
        integrator=dict(type="volpath", max_depth=a.max_depth),
        seconds=round(secs, 2),
        pattern=pattern,
        wall_grid=list(sc["wall"]["grid"]), wall_supersample=sc["wall"]["m"],
        scene_grid=[nu, nv],
        rows=int(len(i)),
        median_rel_stderr=float(np.nanmedian(rel)),
        blocks=info,
        flip_rows=a.flip_rows,
    )
    with open(out / "render.json", "w") as f:
        json.dump(meta, f, indent=1)
        f.write("\n")
    print(f"{len(i)} rows in {secs:.1f} s, median relative stderr {100*meta['median_rel_stderr']:.3f} %")


if __name__ == "__main__":
    main()
