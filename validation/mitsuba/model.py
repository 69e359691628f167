#!/usr/bin/env python3
"""A literal numpy reading of MODEL.md (revision 3): the transport matrix T and i from frames.

Independent of the Rust crate and of render.py (its own scene-file parsing and
geometry), so that comparing `T @ truth` with a Mitsuba render tests the
contract, not shared code.

Covers: both planes with supersampling, lambertian / isotropic emitters,
occluders (parallelogram and ball), the specular GGX term, the diffuse term
(`fresnel` default, `lambert`), no polarizer or an ideal sheet per pose angle
(`absorbing` default, `transmitting`), the on-chip polarizer mosaic (`analyzer =
"mosaic"`, `sensor_deg`, `extinction`, `layout = "polarsens"`). Not covered: linearly
polarized scenes, binning.

Revision 3 ("From camera frames to i"): `pixel_map` (which integer image points
belong to which wall element, their wall points and footprints a_p), `measure`
(i_j and var_j of a frame), `transport(sc, sampling="pixels")` (rows averaged over
an element's pixels, weights a_p). `python3 model.py --selfcheck` runs the checks.

Mosaic ("On-chip polarizer mosaic", written from MODEL.md): a pose with `analyzer =
"mosaic"` gives four blocks, theta_k = 0, 45, 90, 135 in that order; block k's analyzer is
the sheet's effective axis t (same n_p, same [polarizer] model) of q(psi), psi = sensor_deg +
theta_k; with `extinction` E every polarization factor (specular and diffuse) is
P(t) + P(t_perp)/E, t_perp = normalize(w_o x t). Under sampling = "pixels" block k averages
over the element's integer image points (x, y) whose micro-polarizer is theta_k (Polarsens:
(y % 2, x % 2) = (0,0) 90, (0,1) 45, (1,0) 135, (1,1) 0 degrees), weights a_p normalized over
those points. Choices where MODEL.md is silent (errors name the key): `sensor_deg`,
`extinction` or `layout` on a pose without `analyzer = "mosaic"` is an error, as is any
`polarizer_deg` key (even []) beside `analyzer = "mosaic"`, an `analyzer` other than
"mosaic", and an `extinction` that is not finite and >= 1; an element with no pixel of one
angle is an error naming the element, the pose and the angle.

Usage as a check against a rendered case:

    python3 validation/mitsuba/model.py tests/data/rendered/crossed \
        [--scene-supersample 4] [--polarizer-model transmitting] [--diffuse lambert]

prints the least-squares gain of the render against T l, the residual
RMS(i - T l)/RMS(i), the render's noise RMS(sigma)/RMS(i), per block and in
total.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import tomllib
from pathlib import Path

import numpy as np


# ---------------------------------------------------------------- scene file
def _unit(x, key):
    x = np.asarray(x, dtype=float)
    n = np.linalg.norm(x)
    if not n > 0:
        raise ValueError(f"{key}: zero vector")
    return x / n


def _plane(d, key):
    n = _unit(d["normal"], f"{key}.normal")
    u = np.asarray(d["u_axis"], dtype=float)
    u = u - np.dot(u, n) * n
    u = _unit(u, f"{key}.u_axis")
    v = np.cross(n, u)
    return {
        "c": np.asarray(d["center"], dtype=float),
        "n": n,
        "u": u,
        "v": v,
        "size": (float(d["size"][0]), float(d["size"][1])),
        "grid": (int(d["grid"][0]), int(d["grid"][1])),
        "m": int(d.get("supersample", 1)),
    }


def load(path, scene_supersample=None, wall_supersample=None):
    with open(path, "rb") as f:
        raw = tomllib.load(f)
    w, s = raw["wall"], raw["scene"]
    sc = {
        "wall": _plane(w, "wall"),
        "scene": _plane(s, "scene"),
        "alpha": float(w["roughness"]),
        "eta": float(w["ior"]),
        "ks": float(w.get("ks", 1.0)),
        "kd": float(w.get("kd", 0.0)),
        "diffuse": w.get("diffuse", "fresnel"),
        "polmodel": raw.get("polarizer", {}).get("model", "absorbing"),
        "emitter": s.get("emitter", "lambertian"),
        "sampling": w.get("sampling", "uniform"),
        "poses": [],
        "occluders": [],
    }
    if "polarization" in s:
        raise NotImplementedError("polarized scenes are not covered by this check")
    if scene_supersample:
        sc["scene"]["m"] = scene_supersample
    if wall_supersample:
        sc["wall"]["m"] = wall_supersample
    for p in raw["pose"]:
        sc["poses"].append(_pose(p))
    for oc in raw.get("occluder", []):
        if "rect" in oc:
            r = oc["rect"]
            sc["occluders"].append(("rect", np.asarray(r["center"], float),
                                    np.asarray(r["half_u"], float), np.asarray(r["half_v"], float)))
        elif "sphere" in oc:
            r = oc["sphere"]
            sc["occluders"].append(("sphere", np.asarray(r["center"], float), float(r["radius"])))
        else:
            raise ValueError("occluder: neither rect nor sphere")
    return sc


# micro-polarizer angle (degrees) -> (row, col) = (y mod 2, x mod 2) of its pixels
LAYOUTS = {"polarsens": {90.0: (0, 0), 45.0: (0, 1), 135.0: (1, 0), 0.0: (1, 1)}}
MOSAIC_THETAS = (0.0, 45.0, 90.0, 135.0)


def _pose(p):
    """One [[pose]] table -> dict (name, o, deg, H, analyzer, sensor_deg, E, layout)."""
    name = p.get("name", "")
    out = {
        "name": name,
        "o": np.asarray(p["camera"], dtype=float),
        "deg": [float(a) for a in p.get("polarizer_deg", [])],
        "H": np.asarray(p["homography"], dtype=float) if "homography" in p else None,
        "analyzer": None, "sensor_deg": 0.0, "E": None, "layout": "polarsens",
    }
    if "analyzer" in p:
        if p["analyzer"] != "mosaic":
            raise ValueError(f"pose {name}: analyzer = {p['analyzer']!r} (only \"mosaic\")")
        if "polarizer_deg" in p:
            raise ValueError(f"pose {name}: analyzer = \"mosaic\" together with polarizer_deg")
        out["analyzer"] = "mosaic"
        out["sensor_deg"] = float(p.get("sensor_deg", 0.0))
        if "extinction" in p:
            E = float(p["extinction"])
            if not (math.isfinite(E) and E >= 1.0):
                raise ValueError(f"pose {name}: extinction = {E} (finite, >= 1)")
            out["E"] = E
        out["layout"] = p.get("layout", "polarsens")
        if out["layout"] not in LAYOUTS:
            raise ValueError(f"pose {name}: layout = {out['layout']!r} (only \"polarsens\")")
    else:
        for k in ("sensor_deg", "extinction", "layout"):
            if k in p:
                raise ValueError(f"pose {name}: {k} without analyzer = \"mosaic\"")
    return out


def pose_blocks(pose):
    """The row blocks of a pose in MODEL.md order: list of dicts
    label (as in build()'s labels), psi (radians or None = no polarizer), E (None = ideal),
    cell ((y % 2, x % 2) of the block's pixels, None = every pixel)."""
    if pose.get("analyzer") == "mosaic":
        lay = LAYOUTS[pose["layout"]]
        return [{"label": (pose["name"], "mosaic", th),
                 "psi": math.radians(pose["sensor_deg"] + th),
                 "E": pose["E"], "cell": lay[th]} for th in MOSAIC_THETAS]
    if not pose["deg"]:
        return [{"label": (pose["name"], None), "psi": None, "E": None, "cell": None}]
    return [{"label": (pose["name"], d), "psi": math.radians(d), "E": None, "cell": None}
            for d in pose["deg"]]


def samples(pl):
    """Sub-sample points, shape (nv*nu, m*m, 3), element index iv*nu+iu."""
    nu, nv = pl["grid"]
    su, sv = pl["size"]
    m = pl["m"]
    iu = np.arange(nu)
    iv = np.arange(nv)
    a = (np.arange(m) + 0.5) / m
    # x[iu, a], y[iv, b] in plane coordinates (metres from centre)
    x = ((iu[:, None] + a[None, :]) / nu - 0.5) * su
    y = ((iv[:, None] + a[None, :]) / nv - 0.5) * sv
    X = x[None, :, None, :]            # (1, nu, 1, m)   iv, iu, b, a
    Y = y[:, None, :, None]            # (nv, 1, m, 1)
    X, Y = np.broadcast_arrays(X, Y)
    P = pl["c"] + X[..., None] * pl["u"] + Y[..., None] * pl["v"]
    return P.reshape(nv * nu, m * m, 3)


# ------------------------------------------------------------------- optics
def fresnel_rs_rp(phi, eta):
    """Rs, Rp at incidence angle phi (array), MODEL.md Eqs. 6-8 with the limit."""
    phi = np.asarray(phi, dtype=float)
    r0 = ((eta - 1.0) / (eta + 1.0)) ** 2
    small = phi < 1e-7
    ph = np.where(small, 0.5, phi)
    pt = np.arcsin(np.sin(ph) / eta)
    rs = np.sin(ph - pt) ** 2 / np.sin(ph + pt) ** 2
    rp = np.tan(ph - pt) ** 2 / np.tan(ph + pt) ** 2
    return np.where(small, r0, rs), np.where(small, r0, rp)


def _normalize(x):
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def crossed_axis(sc, o, psi):
    """n_p and q(psi) of a pose (MODEL.md 'The crossed polarizer of a pose')."""
    c0 = sc["wall"]["c"]
    s0 = sc["scene"]["c"]
    n_p = _normalize(c0 - o)
    wi0 = _normalize(s0 - c0)
    wo0 = _normalize(o - c0)
    es0 = np.cross(wi0, wo0)
    if np.linalg.norm(es0) < 1e-12:
        raise ValueError("pose: crossed axis undefined (w_i0 parallel to w_o0)")
    es0 = _normalize(es0)
    q0 = _normalize(np.cross(es0, n_p))
    # Rodrigues by +psi about n_p
    q = (q0 * math.cos(psi) + np.cross(n_p, q0) * math.sin(psi)
         + n_p * np.dot(n_p, q0) * (1 - math.cos(psi)))
    return n_p, q


def visible(S, C, occluders):
    """V for segments S->C (broadcast arrays (..., 3)); open segment vs closed shapes."""
    V = np.ones(np.broadcast_shapes(S.shape, C.shape)[:-1], dtype=bool)
    D = C - S
    for oc in occluders:
        if oc[0] == "rect":
            _, ce, hu, hv = oc
            nrm = np.cross(hu, hv)
            den = D @ nrm
            num = (ce - S) @ nrm
            with np.errstate(divide="ignore", invalid="ignore"):
                t = num / den
            ok = (np.abs(den) > 1e-300) & (t > 0) & (t < 1)
            P = S + np.where(ok, t, 0.0)[..., None] * D - ce
            # coordinates in (hu, hv): solve the 2x2 Gram system
            g = np.array([[hu @ hu, hu @ hv], [hu @ hv, hv @ hv]])
            gi = np.linalg.inv(g)
            b = np.stack([P @ hu, P @ hv], axis=-1)
            ab = b @ gi.T
            inside = (np.abs(ab[..., 0]) <= 1) & (np.abs(ab[..., 1]) <= 1)
            V &= ~(ok & inside)
        else:
            _, ce, r = oc
            # |S + t D - ce|^2 = r^2
            f = S - ce
            a = np.sum(D * D, -1)
            b = 2 * np.sum(f * D, -1)
            c = np.sum(f * f, -1) - r * r
            disc = b * b - 4 * a * c
            sq = np.sqrt(np.maximum(disc, 0))
            t1 = (-b - sq) / (2 * a)
            t2 = (-b + sq) / (2 * a)
            V &= ~((disc >= 0) & (t1 < 1) & (t2 > 0))
    return V


def block(sc, pose, psi=None, polmodel=None, diffuse=None, cols=None, E=None):
    """T rows of one block: (n_wall, n_scene). psi in radians, None = no polarizer.
    cols: only these columns (scene element indices), e.g. where a truth is non-zero.
    E: extinction ratio of the analyzer (None = ideal): factor P(t) + P(t_perp)/E."""
    W = samples(sc["wall"])            # (J, mw, 3)
    S = samples(sc["scene"])           # (K, ms, 3)
    if cols is not None:
        S = S[cols]
    J, mw, _ = W.shape
    K, ms, _ = S.shape
    step = max(1, (1 << 21) // (mw * K * ms))   # wall elements per chunk (memory)
    return np.vstack([_block(sc, pose, psi, polmodel, diffuse, W[j:j + step], S, E)
                      for j in range(0, J, step)])


def _block(sc, pose, psi, polmodel, diffuse, W, S, E=None):
    polmodel = polmodel or sc["polmodel"]
    diffuse = diffuse or sc["diffuse"]
    J, mw, _ = W.shape
    K, ms, _ = S.shape
    n = sc["wall"]["n"]
    ns = sc["scene"]["n"]
    su, sv = sc["scene"]["size"]
    nu, nv = sc["scene"]["grid"]
    a_k = su / nu * sv / nv
    alpha, eta, ks, kd = sc["alpha"], sc["eta"], sc["ks"], sc["kd"]
    o = pose["o"]
    if psi is not None:
        n_p, q = crossed_axis(sc, o, psi)

    C = W.reshape(J * mw, 3)[:, None, :]        # (Jw, 1, 3)
    Sp = S.reshape(K * ms, 3)[None, :, :]       # (1, Ks, 3)
    d = Sp - C
    r2 = np.sum(d * d, -1)
    wi = d / np.sqrt(r2)[..., None]
    wo = _normalize(o - C)                       # (Jw, 1, 3)
    ni = wi @ n
    no = (wo @ n)                                # (Jw, 1)
    if sc["emitter"] == "lambertian":
        g = np.maximum(0.0, -(wi @ ns))          # n_s . (c - s)/|c - s|
    else:
        g = np.ones_like(ni)
    V = visible(Sp, C, sc["occluders"]) if sc["occluders"] else True

    # specular
    h = _normalize(wi + wo)
    nh = h @ n
    D = alpha ** 2 / (math.pi * (nh ** 2 * (alpha ** 2 - 1) + 1) ** 2)

    def G1(c):
        c = np.maximum(c, 1e-300)
        return 2 * c / (c + np.sqrt(alpha ** 2 + (1 - alpha ** 2) * c ** 2))

    G2 = G1(ni) * G1(no)
    theta_h = 0.5 * np.arccos(np.clip(np.sum(wi * wo, -1), -1, 1))
    Rs, Rp = fresnel_rs_rp(theta_h, eta)

    if psi is None:
        Pspec = (Rs + Rp) / 2
    else:
        if polmodel == "absorbing":
            a_ax = np.cross(n_p, q)
            t = _normalize(np.cross(wo, a_ax))
        elif polmodel == "transmitting":
            t = _normalize(q - (wo @ q)[..., None] * wo)
        else:
            raise ValueError(f"polarizer.model: {polmodel}")
        # partial analyzer (mosaic extinction E): the second principal axis, normal to t and w_o
        axes = [(t, 1.0)] if E is None else [(t, 1.0), (_normalize(np.cross(wo, t)), 1.0 / E)]
        es = np.cross(wi, wo)
        nes = np.linalg.norm(es, axis=-1)
        degenerate = nes < 1e-12
        es = es / np.where(degenerate, 1.0, nes)[..., None]
        ep = np.cross(es, wo)
        Pspec = 0.0
        for tt, wgt in axes:
            ts = np.sum(tt * es, -1)
            tp = np.sum(tt * ep, -1)
            Pspec = Pspec + wgt * np.where(degenerate, Rs / 2, (Rs * ts ** 2 + Rp * tp ** 2) / 2)

    with np.errstate(divide="ignore", invalid="ignore"):
        fspec = ks * D * G2 / (4 * ni * no) * Pspec
    f = fspec
    if kd != 0.0:
        if diffuse == "fresnel":
            th_i = np.arccos(np.clip(ni, -1, 1))
            Rsi, Rpi = fresnel_rs_rp(th_i, eta)
            T_in = 1 - (Rsi + Rpi) / 2
            th_o = np.arccos(np.clip(no, -1, 1))
            Rso, Rpo = fresnel_rs_rp(th_o, eta)
            if psi is None:
                Pd = T_in * (1 - (Rso + Rpo) / 2)
            else:
                eso = np.cross(n, wo)
                neso = np.linalg.norm(eso, axis=-1, keepdims=True)
                eso = np.where(neso < 1e-12, np.cross(n, np.array([1.0, 0, 0])), eso / np.maximum(neso, 1e-300))
                eso = _normalize(eso)
                epo = np.cross(eso, wo)
                Pd = 0.0
                for tt, wgt in axes:
                    Pd = Pd + wgt * T_in * ((1 - Rso) * np.sum(tt * eso, -1) ** 2
                                            + (1 - Rpo) * np.sum(tt * epo, -1) ** 2) / 2
        elif diffuse == "lambert":
            Pd = 1.0 if psi is None else sum(0.5 * wgt for _, wgt in axes)
        else:
            raise ValueError(f"wall.diffuse: {diffuse}")
        f = f + kd / math.pi * Pd

    with np.errstate(divide="ignore", invalid="ignore"):
        E = a_k * g * ni / r2 * f * V
    E = np.where((ni > 0) & (no > 0) & np.isfinite(E), E, 0.0)
    E = E.reshape(J, mw, K, ms).mean(axis=(1, 3))
    return E


def build(sc, **kw):
    """Full stacked T and the (pose, deg) list of its blocks."""
    blocks, labels = [], []
    for p in sc["poses"]:
        for b in pose_blocks(p):
            blocks.append(block(sc, p, b["psi"], E=b["E"], **kw))
            labels.append(b["label"])
    return np.vstack(blocks), labels


# ------------------------------------------- revision 3: from camera frames to i
def _wall_geometry(wall):
    """(size_u, size_v), (nu, nv) of a wall given as model.py's plane dict or a scene dict."""
    if "wall" in wall:
        wall = wall["wall"]
    return wall["size"], wall["grid"]


def pixel_map(H, wall, frame=None):
    """The integer image points that belong to wall elements (MODEL.md 'From camera frames to i').

    H: 3x3, wall (u, v) in metres relative to the wall centre -> pixel (x, y), pixel centres
    at integers. frame: None = the whole image plane; [x0, y0, width, height] = only the
    pixels x0 <= x < x0 + width, y0 <= y < y0 + height.

    Returns a dict of 1-D arrays over the pixels (raster order, y outer, x inner):
      x, y   int64 pixel coordinates
      j      int64 element index iv*nu + iu (element (iu, iv) spans u in
             [(iu/nu - 1/2) su, ((iu+1)/nu - 1/2) su), likewise v)
      u, v   float64 wall point H^-1(x, y)
      a      float64 footprint |det J(H^-1)| at (x, y), m^2 per pixel
      margin float64 distance of (u, v) to the nearest element border, in element widths
             (for judging whether another implementation's rounding could move the pixel)
    """
    H = np.asarray(H, dtype=float)
    (su, sv), (nu, nv) = _wall_geometry(wall)
    corners = np.array([[-su / 2, -sv / 2, 1], [su / 2, -sv / 2, 1],
                        [su / 2, sv / 2, 1], [-su / 2, sv / 2, 1]]) @ H.T
    if not np.all(corners[:, 2] > 0):
        raise ValueError("homography: a wall corner maps to w <= 0 (behind the camera)")
    cx, cy = corners[:, 0] / corners[:, 2], corners[:, 1] / corners[:, 2]
    # the wall's image is the convex quadrilateral of its corners: its integer points are
    # inside this box
    x0, x1 = math.ceil(cx.min()), math.floor(cx.max())
    y0, y1 = math.ceil(cy.min()), math.floor(cy.max())
    if frame is not None:
        fx, fy, fw, fh = (int(t) for t in frame)
        x0, x1 = max(x0, fx), min(x1, fx + fw - 1)
        y0, y1 = max(y0, fy), min(y1, fy + fh - 1)
    xs = np.arange(x0, x1 + 1, dtype=np.int64)
    ys = np.arange(y0, y1 + 1, dtype=np.int64)
    X, Y = np.meshgrid(xs, ys)            # (ny, nx): y outer, x inner
    X, Y = X.ravel(), Y.ravel()
    G = np.linalg.inv(H)
    P = np.stack([X, Y, np.ones_like(X)], axis=-1).astype(float) @ G.T
    w = P[:, 2]
    u, v = P[:, 0] / w, P[:, 1] / w
    fu = (u / su + 0.5) * nu              # element coordinate along u (element iu: [iu, iu+1))
    fv = (v / sv + 0.5) * nv
    iu, iv = np.floor(fu), np.floor(fv)
    keep = (iu >= 0) & (iu < nu) & (iv >= 0) & (iv < nv)
    # det J of p -> (Gp)_{1,2} / (Gp)_3 is det(G) / ((Gp)_3)^3
    a = np.abs(np.linalg.det(G) / w ** 3)
    margin = np.minimum(np.minimum(fu - iu, iu + 1 - fu), np.minimum(fv - iv, iv + 1 - fv))
    return {
        "x": X[keep], "y": Y[keep],
        "j": (iv * nu + iu).astype(np.int64)[keep],
        "u": u[keep], "v": v[keep], "a": a[keep], "margin": margin[keep],
    }


def measure(frame_array, H, wall, variance=None):
    """i_j = sum a_p x_p / sum a_p and var_j = sum a_p^2 var_p / (sum a_p)^2 (MODEL.md rev 3).

    frame_array: (height, width), pixel (x, y) = frame_array[y, x] (region offset 0, no
    binning), already dark-subtracted and averaged. variance: the same shape, the variance
    of each pixel's mean (optional). Every pixel of the image plane whose H^-1 lies in an
    element must be inside the frame, and every element must have a pixel; otherwise
    ValueError naming the first bad element.
    Returns (i, var) as float64 arrays of length nu*nv (var None without `variance`).
    """
    frame_array = np.asarray(frame_array)
    hgt, wid = frame_array.shape
    (_, _), (nu, nv) = _wall_geometry(wall)
    pm = pixel_map(H, wall)
    out = (pm["x"] < 0) | (pm["x"] >= wid) | (pm["y"] < 0) | (pm["y"] >= hgt)
    if np.any(out):
        j = int(pm["j"][out].min())
        raise ValueError(f"wall element (iu {j % nu}, iv {j // nu}): pixels outside the frame")
    count = np.bincount(pm["j"], minlength=nu * nv)
    if np.any(count == 0):
        j = int(np.flatnonzero(count == 0)[0])
        raise ValueError(f"wall element (iu {j % nu}, iv {j // nu}): no pixel")
    a = pm["a"]
    xp = frame_array[pm["y"], pm["x"]].astype(np.float64)
    A = np.bincount(pm["j"], weights=a, minlength=nu * nv)
    i = np.bincount(pm["j"], weights=a * xp, minlength=nu * nv) / A
    var = None
    if variance is not None:
        vp = np.asarray(variance)[pm["y"], pm["x"]].astype(np.float64)
        var = np.bincount(pm["j"], weights=a * a * vp, minlength=nu * nv) / A ** 2
    return i, var


def _entries(sc, pose, psi, P, cols=None, E=None, **kw):
    """T entries for single wall points P (N, 3), averaged over scene sub-samples: (N, K)."""
    S = samples(sc["scene"])
    if cols is not None:
        S = S[cols]
    K, ms, _ = S.shape
    step = max(1, (1 << 21) // (K * ms))
    W = P[:, None, :]
    return np.vstack([_block(sc, pose, psi, kw.get("polmodel"), kw.get("diffuse"), W[i:i + step], S, E)
                      for i in range(0, len(P), step)])


def cell_pixel_map(H, wall, cell=None):
    """pixel_map restricted to the integer points (x, y) with (y % 2, x % 2) == cell
    (None: all of them)."""
    pm = pixel_map(H, wall)
    if cell is None:
        return pm
    keep = (pm["y"] % 2 == cell[0]) & (pm["x"] % 2 == cell[1])
    return {k: v[keep] for k, v in pm.items()}


def pixel_block(sc, pose, psi=None, E=None, cell=None, **kw):
    """T rows of one block with sampling = "pixels": entry averaged over the wall points
    H^-1(p) of element j's pixels p, weights a_p / sum a_p (p over the whole image plane;
    with `cell` = (row, col) only the points with (y % 2, x % 2) == cell, a mosaic angle)."""
    wall = sc["wall"]
    nu, nv = wall["grid"]
    pm = cell_pixel_map(pose["H"], wall, cell)
    count = np.bincount(pm["j"], minlength=nu * nv)
    if np.any(count == 0):
        j = int(np.flatnonzero(count == 0)[0])
        what = "" if cell is None else f" of mosaic cell (y%2, x%2) = {tuple(cell)}"
        raise ValueError(f"pose {pose['name']}: wall element (iu {j % nu}, iv {j // nu}) has no pixel{what}")
    order = np.argsort(pm["j"], kind="stable")
    j, a = pm["j"][order], pm["a"][order]
    P = wall["c"] + pm["u"][order, None] * wall["u"] + pm["v"][order, None] * wall["v"]
    Ent = _entries(sc, pose, psi, P, E=E, **kw)                # (Npix, K)
    A = np.bincount(j, weights=a, minlength=nu * nv)
    starts = np.concatenate([[0], np.cumsum(count)[:-1]])
    return np.add.reduceat(Ent * (a / A[j])[:, None], starts, axis=0)


def transport(sc, sampling="pixels", **kw):
    """Stacked T with `sampling` ("uniform" or "pixels"; None = the scene file's value).
    "pixels" applies to poses with a homography; a pose without one gets uniform rows."""
    sampling = sampling or sc["sampling"]
    if sampling not in ("uniform", "pixels"):
        raise ValueError(f"wall.sampling: {sampling}")
    blocks, labels = [], []
    for p in sc["poses"]:
        pix = sampling == "pixels" and p["H"] is not None
        for b in pose_blocks(p):
            if pix:
                blocks.append(pixel_block(sc, p, b["psi"], E=b["E"], cell=b["cell"], **kw))
            else:
                blocks.append(block(sc, p, b["psi"], E=b["E"], **kw))
            labels.append(b["label"])
    return np.vstack(blocks), labels


def selfcheck(scene_file=None):
    """Checks of the revision-3 functions; raises AssertionError on failure."""
    root = Path(__file__).resolve().parents[2]
    scene_file = scene_file or root / "config/scenes/brewster-crossed-3x3.toml"
    sc = load(scene_file)
    H = sc["poses"][0]["H"]
    wall = sc["wall"]
    pm = pixel_map(H, wall)
    su, sv = wall["size"]
    # footprints: det J against central differences of H^-1, and sum a_p ~ wall area
    G = np.linalg.inv(H)
    def inv(x, y):
        p = G @ np.array([x, y, 1.0])
        return p[:2] / p[2]
    for k in np.linspace(0, len(pm["x"]) - 1, 7).astype(int):
        x, y, e = float(pm["x"][k]), float(pm["y"][k]), 1e-3
        J = np.column_stack([(inv(x + e, y) - inv(x - e, y)) / (2 * e), (inv(x, y + e) - inv(x, y - e)) / (2 * e)])
        assert abs(abs(np.linalg.det(J)) / pm["a"][k] - 1) < 1e-6
    area = pm["a"].sum()
    assert abs(area / (su * sv) - 1) < 0.01, area
    # every wall point is inside its element; the frame restriction is a subset
    nu, nv = wall["grid"]
    iu, iv = pm["j"] % nu, pm["j"] // nu
    assert np.all((pm["u"] >= (iu / nu - 0.5) * su) & (pm["u"] < ((iu + 1) / nu - 0.5) * su))
    assert np.all((pm["v"] >= (iv / nv - 0.5) * sv) & (pm["v"] < ((iv + 1) / nv - 0.5) * sv))
    sub = pixel_map(H, wall, frame=[100, 50, 200, 300])
    assert np.all((sub["x"] >= 100) & (sub["x"] < 300) & (sub["y"] >= 50) & (sub["y"] < 350))
    assert len(sub["x"]) == np.sum((pm["x"] >= 100) & (pm["x"] < 300) & (pm["y"] >= 50) & (pm["y"] < 350))
    # measure: a flat frame gives the flat value; var of a flat variance frame
    flat = np.full((512, 512), 0.37, dtype=np.float32)
    i, var = measure(flat, H, wall, variance=np.full((512, 512), 4.0))
    assert np.allclose(i, np.float64(np.float32(0.37)), rtol=1e-12, atol=0)
    A = np.bincount(pm["j"], weights=pm["a"])
    A2 = np.bincount(pm["j"], weights=pm["a"] ** 2)
    assert np.allclose(var, 4.0 * A2 / A ** 2, rtol=1e-12)
    # a frame that is affine in the wall coordinates measures the a-weighted centroid
    # a frame linear in x measures the weighted mean of x
    lin = np.tile(np.arange(512, dtype=float), (512, 1))
    i, _ = measure(lin, H, wall)
    assert np.allclose(i, np.bincount(pm["j"], weights=pm["a"] * pm["x"]) / A, rtol=1e-12)
    # uniform sampling through transport() is the existing build()
    T0, lab0 = build(sc)
    T1, lab1 = transport(sc, "uniform")
    assert lab0 == lab1 and np.array_equal(T0, T1)
    # pixels rows: close to finely supersampled uniform rows, not equal
    T2, _ = transport(sc, "pixels")
    T8, _ = transport(load(scene_file, wall_supersample=8), "uniform")
    rel = np.sqrt(np.mean((T2 - T8) ** 2) / np.mean(T8 ** 2))
    assert 1e-5 < rel < 0.02, rel
    print(f"selfcheck ok ({Path(scene_file).name}): {len(pm['x'])} pixels, sum a_p / wall area"
          f" {area / (su * sv):.6f}, pixels per element {int(np.bincount(pm['j']).min())}-"
          f"{int(np.bincount(pm['j']).max())}, min border margin {pm['margin'].min():.2e} elements,"
          f" rms(T_pixels - T_uniform m=8)/rms {rel:.2e}")
    return True


# ------------------------------------------------------------- mosaic self-check
def _hand_entry(sc, o, psi, E, c, s):
    """One T entry at wall point c, scene point s written out scalar by scalar (no
    vectorized code shared with _block): MODEL.md 'One entry of T' with the mosaic factor
    P(t) + P(t_perp)/E (E None: ideal). No occluder test (use an unblocked pair)."""
    def dot(a, b):
        return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]

    def cross(a, b):
        return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]

    def unit(a):
        L = math.sqrt(dot(a, a))
        return [x / L for x in a]

    def sub(a, b):
        return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]

    def fres(phi, eta):
        if phi < 1e-7:
            r = ((eta - 1) / (eta + 1)) ** 2
            return r, r
        pt = math.asin(math.sin(phi) / eta)
        return (math.sin(phi - pt) ** 2 / math.sin(phi + pt) ** 2,
                math.tan(phi - pt) ** 2 / math.tan(phi + pt) ** 2)

    c, s, o = list(map(float, c)), list(map(float, s)), list(map(float, o))
    n = list(sc["wall"]["n"]); ns = list(sc["scene"]["n"])
    alpha, eta, ks, kd = sc["alpha"], sc["eta"], sc["ks"], sc["kd"]
    su, sv = sc["scene"]["size"]; nu, nv = sc["scene"]["grid"]
    d = sub(s, c); r2 = dot(d, d); wi = unit(d); wo = unit(sub(o, c))
    ni, no = dot(n, wi), dot(n, wo)
    if ni <= 0 or no <= 0:
        return 0.0
    g = max(0.0, -dot(ns, wi)) if sc["emitter"] == "lambertian" else 1.0
    # crossed axis and q(psi), Rodrigues about n_p
    c0, s0 = list(sc["wall"]["c"]), list(sc["scene"]["c"])
    n_p = unit(sub(c0, o))
    es0 = unit(cross(unit(sub(s0, c0)), unit(sub(o, c0))))
    q0 = unit(cross(es0, n_p))
    k = cross(n_p, q0); kq = dot(n_p, q0)
    q = [q0[i] * math.cos(psi) + k[i] * math.sin(psi) + n_p[i] * kq * (1 - math.cos(psi)) for i in range(3)]
    if sc["polmodel"] == "absorbing":
        t = unit(cross(wo, cross(n_p, q)))
    else:
        qw = dot(q, wo)
        t = unit([q[i] - qw * wo[i] for i in range(3)])
    tperp = unit(cross(wo, t))
    # specular
    h = unit([wi[i] + wo[i] for i in range(3)])
    nh = dot(n, h)
    D = alpha ** 2 / (math.pi * (nh * nh * (alpha ** 2 - 1) + 1) ** 2)
    G1 = lambda x: 2 * x / (x + math.sqrt(alpha ** 2 + (1 - alpha ** 2) * x * x))
    Rs, Rp = fres(0.5 * math.acos(max(-1.0, min(1.0, dot(wi, wo)))), eta)
    es = unit(cross(wi, wo)); ep = cross(es, wo)
    Pspec_t = (Rs * dot(t, es) ** 2 + Rp * dot(t, ep) ** 2) / 2
    Pspec_p = (Rs * dot(tperp, es) ** 2 + Rp * dot(tperp, ep) ** 2) / 2
    Pspec = Pspec_t + (0.0 if E is None else Pspec_p / E)
    f = ks * D * G1(ni) * G1(no) / (4 * ni * no) * Pspec
    if kd:
        if sc["diffuse"] == "fresnel":
            Rsi, Rpi = fres(math.acos(ni), eta)
            Tin = 1 - (Rsi + Rpi) / 2
            Rso, Rpo = fres(math.acos(no), eta)
            eso = unit(cross(n, wo)); epo = cross(eso, wo)
            Pd_t = Tin * ((1 - Rso) * dot(t, eso) ** 2 + (1 - Rpo) * dot(t, epo) ** 2) / 2
            Pd_p = Tin * ((1 - Rso) * dot(tperp, eso) ** 2 + (1 - Rpo) * dot(tperp, epo) ** 2) / 2
        else:
            Pd_t = Pd_p = 0.5
        f += kd / math.pi * (Pd_t + (0.0 if E is None else Pd_p / E))
    return su / nu * sv / nv * g * ni / r2 * f


def selfcheck_mosaic(scene_file=None):
    """Mosaic checks; raises AssertionError on failure. Returns a dict of the numbers seen."""
    root = Path(__file__).resolve().parents[2]
    scene_file = scene_file or root / "config/scenes/occluder-multi-3x3.toml"
    res = {}

    def mosaic(sc, sensor_deg=0.0, E=None):
        for p in sc["poses"]:
            p.update(analyzer="mosaic", sensor_deg=sensor_deg, E=E, layout="polarsens", deg=[])
        return sc

    # (1) ideal mosaic at sensor_deg 0, uniform rows == sheet at [0, 45, 90, 135]
    worst = 0.0
    for polmodel in ("absorbing", "transmitting"):
        for kd, diffuse in ((0.0, "fresnel"), (0.1, "fresnel"), (0.1, "lambert")):
            sheet = load(scene_file, wall_supersample=2)
            sheet.update(polmodel=polmodel, kd=kd, diffuse=diffuse)
            for p in sheet["poses"]:
                p["deg"] = [0.0, 45.0, 90.0, 135.0]
            mos = mosaic(load(scene_file, wall_supersample=2))
            mos.update(polmodel=polmodel, kd=kd, diffuse=diffuse)
            Ts, ls = transport(sheet, "uniform")
            Tm, lm = transport(mos, "uniform")
            assert Ts.shape == Tm.shape and [l[1] for l in ls] == [l[2] for l in lm]
            err = float(np.abs(Ts - Tm).max() / np.abs(Ts).max())
            assert err <= 1e-12, (polmodel, kd, diffuse, err)
            worst = max(worst, err)
    res["ideal_mosaic_vs_sheet_max_rel"] = worst

    # (2) E = 1: t and t_perp pass equally, the factor is the unpolarized one (Rs+Rp)/2 and
    #     T_in (1 - (Rs+Rp)/2) (fresnel), 1/2 + 1/2 (lambert): every block == no-polarizer block
    worst = 0.0
    for polmodel in ("absorbing", "transmitting"):
        for diffuse in ("fresnel", "lambert"):
            nop = load(scene_file); nop.update(polmodel=polmodel, kd=0.1, diffuse=diffuse)
            for p in nop["poses"]:
                p["deg"] = []
            T0, _ = transport(nop, "uniform")
            mos = mosaic(load(scene_file), sensor_deg=17.0, E=1.0)
            mos.update(polmodel=polmodel, kd=0.1, diffuse=diffuse)
            Tm, _ = transport(mos, "uniform")
            nb = Tm.shape[0] // T0.shape[0]              # 4 mosaic blocks per no-polarizer block
            assert nb == 4
            J = T0.shape[0] // len(nop["poses"])
            for ip in range(len(nop["poses"])):
                ref = T0[ip * J:(ip + 1) * J]
                for k in range(nb):
                    blk = Tm[(ip * nb + k) * J:(ip * nb + k + 1) * J]
                    worst = max(worst, float(np.abs(blk - ref).max() / np.abs(ref).max()))
    assert worst <= 1e-12, worst
    res["E1_vs_nopolarizer_max_rel"] = worst

    # (3) one entry with E against the scalar hand computation, and P(t) + P(t_perp)/E as the
    #     sum of an ideal block at t and the same E=inf computation with t_perp
    worst = 0.0
    for polmodel in ("absorbing", "transmitting"):
        for diffuse in ("fresnel", "lambert"):
            for E in (None, 300.0, 7.0):
                sc = mosaic(load(scene_file), sensor_deg=-20.0, E=E)
                sc.update(polmodel=polmodel, kd=0.1, diffuse=diffuse)
                sc["occluders"] = []
                pose = sc["poses"][0]
                W = samples(sc["wall"]); S = samples(sc["scene"])
                for b in pose_blocks(pose):
                    T = block(sc, pose, b["psi"], E=b["E"])
                    for j, kk in ((0, 0), (517, 4), (1023, 8), (300, 2)):
                        h = _hand_entry(sc, pose["o"], b["psi"], b["E"], W[j, 0], S[kk, 0])
                        worst = max(worst, abs(T[j, kk] - h) / abs(h))
    assert worst <= 1e-12, worst
    res["E_entry_vs_hand_max_rel"] = worst

    # (4) pixels: the four cells partition each element's full-frame pixel set; the
    #     a-weighted combination of the cells' rows at one angle is the full-frame row
    sc = load(scene_file); sc.update(kd=0.1)
    lay = LAYOUTS["polarsens"]
    assert sorted(lay.values()) == [(0, 0), (0, 1), (1, 0), (1, 1)]
    stats = {}
    for pose in sc["poses"]:
        full = pixel_map(pose["H"], sc["wall"])
        key = lambda pm: set(zip(pm["x"].tolist(), pm["y"].tolist(), pm["j"].tolist()))
        cells = {th: cell_pixel_map(pose["H"], sc["wall"], lay[th]) for th in MOSAIC_THETAS}
        sets = {th: key(pm) for th, pm in cells.items()}
        union = set().union(*sets.values())
        assert union == key(full)
        assert sum(len(v) for v in sets.values()) == len(full["x"])
        for th, pm in cells.items():
            r, cc = lay[th]
            assert np.all(pm["y"] % 2 == r) and np.all(pm["x"] % 2 == cc)
        nu, nv = sc["wall"]["grid"]
        counts = {th: np.bincount(pm["j"], minlength=nu * nv) for th, pm in cells.items()}
        assert np.array_equal(sum(counts.values()), np.bincount(full["j"], minlength=nu * nv))
        psi = math.radians(33.0)
        Tfull = pixel_block(sc, pose, psi, E=50.0)
        A = {th: np.bincount(pm["j"], weights=pm["a"], minlength=nu * nv) for th, pm in cells.items()}
        comb = sum(A[th][:, None] * pixel_block(sc, pose, psi, E=50.0, cell=lay[th]) for th in MOSAIC_THETAS)
        comb /= sum(A.values())[:, None]
        err = float(np.abs(comb - Tfull).max() / np.abs(Tfull).max())
        assert err <= 1e-12, err
        # how far one angle's sub-lattice rows are from the full-frame rows of that angle
        d = [float(np.sqrt(np.mean((pixel_block(sc, pose, psi, cell=lay[th]) - pixel_block(sc, pose, psi)) ** 2)
                           / np.mean(pixel_block(sc, pose, psi) ** 2))) for th in (0.0,)]
        stats[pose["name"]] = {"cell_pixels_per_element_min": int(min(c.min() for c in counts.values())),
                               "cell_pixels_per_element_max": int(max(c.max() for c in counts.values())),
                               "combined_cells_vs_full_max_rel": err,
                               "cell0_vs_full_rms_rel": d[0]}
    res["pixels"] = stats
    print(f"selfcheck_mosaic ok ({Path(scene_file).name}): {json.dumps(res)}")
    return res


# ------------------------------------------------------------------ compare
def compare(case, scene_supersample=None, polmodel=None, diffuse=None, quiet=False, scene=None):
    case = Path(case)
    sc = load(scene or case / "scene.toml", scene_supersample=scene_supersample)
    T, labels = build(sc, polmodel=polmodel, diffuse=diffuse)
    truth = np.load(case / "truth.npy")
    i = np.load(case / "i.npy")
    sig = np.load(case / "sigma.npy")
    pred = T @ truth.reshape(-1)
    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))
    out = {"blocks": []}
    nb = len(labels)
    nj = len(i) // nb
    for b, lab in enumerate(labels + [("all", "all")]):
        sl = slice(b * nj, (b + 1) * nj) if b < nb else slice(None)
        ii, pp, ss = i[sl], pred[sl], sig[sl]
        gain = float(pp @ ii / (pp @ pp))
        rec = {
            "block": lab,
            "gain": gain,
            "resid_rel": rms(ii - pp) / rms(ii),
            "resid_rel_after_gain": rms(ii - gain * pp) / rms(ii),
            "noise_rel": rms(ss) / rms(ii),
            "chi_rms": rms((ii - pp) / np.where(ss > 0, ss, np.inf)),
        }
        out["blocks"].append(rec)
    if not quiet:
        for r in out["blocks"]:
            print(f"  {str(r['block']):>16}: gain {r['gain']:.5f}  resid {100*r['resid_rel']:.3f} %"
                  f" (after gain {100*r['resid_rel_after_gain']:.3f} %)  noise {100*r['noise_rel']:.3f} %"
                  f"  resid/sigma rms {r['chi_rms']:.2f}")
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cases", nargs="*", help="case directories (scene.toml, truth.npy, i.npy, sigma.npy)")
    ap.add_argument("--selfcheck", nargs="*", metavar="SCENE",
                    help="run the revision-3 self-checks (default scene: config/scenes/brewster-crossed-3x3.toml)")
    ap.add_argument("--scene-supersample", type=int, default=None)
    ap.add_argument("--polarizer-model", default=None, choices=["absorbing", "transmitting"])
    ap.add_argument("--diffuse", default=None, choices=["fresnel", "lambert"])
    ap.add_argument("--scene", default=None, help="scene file (default CASE/scene.toml)")
    ap.add_argument("--json", action="store_true", help="print JSON instead of text")
    a = ap.parse_args()
    if a.selfcheck is not None:
        for f in a.selfcheck or [None]:
            selfcheck(f)
        selfcheck_mosaic()
        if not a.cases:
            return
    if not a.cases:
        ap.error("no case directory given")
    res = {}
    for c in a.cases:
        if not a.json:
            print(c)
        res[c] = compare(c, a.scene_supersample, a.polarizer_model, a.diffuse, quiet=a.json, scene=a.scene)
    if a.json:
        json.dump(res, sys.stdout, indent=1, default=str)
        print()


if __name__ == "__main__":
    main()
