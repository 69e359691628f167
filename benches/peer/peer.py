#!/usr/bin/env python3
"""A straightforward vectorized NumPy peer of polnlos: the same transport
model (MODEL.md revision 2 "One entry of T": either polarizer model, either
diffuse term; no occluder, no supersampling, unpolarized scene) and the same ADMM-TV (lambda = rho = 1e-2 mean diag(T^T T), 200
iterations from zero, isotropic TV with forward differences and Neumann
boundaries, box [0, 1]).

polnlos bench runs it on the same scene file and measurement and compares
both the matrix and the recovery; it is not part of the product.

Usage: peer.py SCENE.toml --wall N --scene-grid N --measurement i.npy --out DIR
              [--iterations K] [--no-save]
Writes DIR/T.npy (float64, C order; not with --no-save), DIR/recovered.npy
and DIR/peer.json.
"""

import argparse
import json
import time
import tomllib

import numpy as np


def unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def plane(d, grid):
    """Element centres (row-major, v outer), normal, element area."""
    n = unit(d["normal"])
    u = np.asarray(d["u_axis"], dtype=float)
    u = unit(u - np.dot(u, n) * n)
    v = np.cross(n, u)
    nu, nv = grid
    su, sv = d["size"]
    fu = ((np.arange(nu) + 0.5) / nu - 0.5) * su
    fv = ((np.arange(nv) + 0.5) / nv - 0.5) * sv
    gu, gv = np.meshgrid(fu, fv)  # (nv, nu)
    pts = np.asarray(d["center"], float) + gu.reshape(-1, 1) * u + gv.reshape(-1, 1) * v
    return pts, n, su / nu * sv / nv


def rotate(v, axis, a):
    return v * np.cos(a) + np.cross(axis, v) * np.sin(a) + axis * np.dot(axis, v) * (1 - np.cos(a))


def smith_g1(c, alpha):
    return 2 * c / (c + np.sqrt(alpha**2 + (1 - alpha**2) * c * c))


def build(cfg, wall_grid, scene_grid):
    w, s = cfg["wall"], cfg["scene"]
    if w.get("supersample", 1) != 1 or s.get("supersample", 1) != 1 or cfg.get("occluder"):
        raise SystemExit("the peer handles supersample = 1 and no occluder only")
    c, n, _ = plane(w, (wall_grid, wall_grid))
    sp, ns, area = plane(s, (scene_grid, scene_grid))
    alpha, eta = w["roughness"], w["ior"]
    ks, kd = w.get("ks", 1.0), w.get("kd", 0.0)
    lambert = s.get("emitter", "lambertian") == "lambertian"
    absorbing = cfg.get("polarizer", {}).get("model", "absorbing") == "absorbing"
    fresnel_diffuse = w.get("diffuse", "fresnel") == "fresnel"
    c0, s0 = np.asarray(w["center"], float), np.asarray(s["center"], float)

    # Per pose and angle: camera and polarizer axis (None: no polarizer).
    blocks = []
    for pose in cfg["pose"]:
        o = np.asarray(pose["camera"], float)
        angles = pose.get("polarizer_deg", [])
        if not angles:
            blocks.append((o, None, None))
            continue
        es0 = unit(np.cross(unit(s0 - c0), unit(o - c0)))
        n_p = unit(c0 - o)
        q0 = unit(np.cross(es0, n_p))
        for a in angles:
            blocks.append((o, rotate(q0, n_p, np.radians(a)), n_p))

    J, K = len(c), len(sp)
    T = np.zeros((len(blocks) * J, K))
    d = sp[None, :, :] - c[:, None, :]  # (J, K, 3) scene minus wall
    r2 = np.einsum("jkx,jkx->jk", d, d)
    wi = d / np.sqrt(r2)[..., None]
    cos_i = wi @ n
    g = np.maximum(0.0, -(wi @ ns)) if lambert else np.ones_like(cos_i)
    base = np.where(cos_i > 0, area * g * cos_i / r2, 0.0)
    g1i = smith_g1(np.maximum(cos_i, 1e-300), alpha)
    t_in = 1 - fresnel_mean(np.clip(cos_i, 0.0, 1.0), eta)
    for b, (o, q, n_p) in enumerate(blocks):
        wo = unit_rows(o - c)  # (J, 3)
        cos_o = wo @ n
        g1o = smith_g1(np.maximum(cos_o, 1e-300), alpha)
        h = wi + wo[:, None, :]
        h /= np.linalg.norm(h, axis=-1, keepdims=True)
        nh = h @ n
        D = alpha**2 / (np.pi * (nh * nh * (alpha**2 - 1) + 1) ** 2)
        cos_io = np.clip(np.einsum("jkx,jx->jk", wi, wo), -1.0, 1.0)
        cphi = np.sqrt((1 + cos_io) / 2)
        sphi2 = 1 - cphi * cphi
        cpt = np.sqrt(1 - sphi2 / eta**2)
        rs = ((cphi - eta * cpt) / (cphi + eta * cpt)) ** 2
        rp = ((eta * cphi - cpt) / (eta * cphi + cpt)) ** 2
        rso, rpo = fresnel(np.clip(cos_o, 0.0, 1.0), eta)
        if q is None:
            P = (rs + rp) / 2
            Pd = t_in * (1 - (rso + rpo) / 2)[:, None] if fresnel_diffuse else 1.0
        else:
            if absorbing:
                t = np.cross(wo, np.cross(n_p, q))
            else:
                t = q - (wo @ q)[:, None] * wo
            t /= np.linalg.norm(t, axis=-1, keepdims=True)
            x = np.cross(wi, wo[:, None, :])
            xn = np.linalg.norm(x, axis=-1)
            es = x / np.maximum(xn, 1e-300)[..., None]
            ep = np.cross(es, wo[:, None, :])
            te_s = np.einsum("jkx,jx->jk", es, t)
            te_p = np.einsum("jkx,jx->jk", ep, t)
            P = np.where(xn < 1e-12, rs / 2, (rs * te_s**2 + rp * te_p**2) / 2)
            if fresnel_diffuse:
                eso = unit_rows(np.cross(n, wo))
                epo = np.cross(eso, wo)
                out = ((1 - rso) * np.einsum("jx,jx->j", t, eso) ** 2
                       + (1 - rpo) * np.einsum("jx,jx->j", t, epo) ** 2) / 2
                Pd = t_in * out[:, None]
            else:
                Pd = 0.5
        ok = (cos_i > 0) & (cos_o[:, None] > 0)
        spec = ks * D * g1i * g1o[:, None] / (4 * np.maximum(cos_i, 1e-300) * cos_o[:, None]) * P
        f = spec + kd / np.pi * Pd
        T[b * J:(b + 1) * J] = np.where(ok, base * f, 0.0)
    return T


def fresnel(c, eta):
    """(Rs, Rp) at cos(angle) c, cosine form (equal to MODEL.md Eqs. 6-8)."""
    ct = np.sqrt(1 - (1 - c * c) / eta**2)
    return ((c - eta * ct) / (c + eta * ct)) ** 2, ((eta * c - ct) / (eta * c + ct)) ** 2


def fresnel_mean(c, eta):
    rs, rp = fresnel(c, eta)
    return (rs + rp) / 2


def unit_rows(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def grad(x, nu, nv):
    img = x.reshape(nv, nu)
    dx = np.zeros_like(img)
    dy = np.zeros_like(img)
    dx[:, :-1] = img[:, 1:] - img[:, :-1]
    dy[:-1, :] = img[1:, :] - img[:-1, :]
    return np.concatenate([dx.ravel(), dy.ravel()])


def grad_t(z, nu, nv):
    n = nu * nv
    zx, zy = z[:n].reshape(nv, nu), z[n:].reshape(nv, nu)
    out = np.zeros((nv, nu))
    out[:, 1:] += zx[:, :-1]
    out[:, :-1] -= zx[:, :-1]
    out[1:, :] += zy[:-1, :]
    out[:-1, :] -= zy[:-1, :]
    return out.ravel()


def admm(T, i, nu, nv, iters=200):
    n = nu * nv
    t0 = time.perf_counter()
    G = T.T @ T
    Ti = T.T @ i
    tg = time.perf_counter()
    lam = 1e-2 * np.mean(np.diag(G))
    rho = lam
    # rho (D^T D + I) as a dense matrix from the operator.
    DtD = np.stack([grad_t(grad(e, nu, nv), nu, nv) for e in np.eye(n)], axis=1)
    L = np.linalg.cholesky(G + rho * (DtD + np.eye(n)))
    Linv = np.linalg.inv(L)
    t1 = time.perf_counter()
    z1, u1 = np.zeros(2 * n), np.zeros(2 * n)
    z2, u2 = np.zeros(n), np.zeros(n)
    k = 0.5 * lam / rho
    for _ in range(iters):
        rhs = Ti + rho * (grad_t(z1 - u1, nu, nv) + z2 - u2)
        l = Linv.T @ (Linv @ rhs)
        dl = grad(l, nu, nv)
        v = dl + u1
        vx, vy = v[:n], v[n:]
        mag = np.hypot(vx, vy)
        shrink = np.where(mag > k, 1 - k / np.maximum(mag, 1e-300), 0.0)
        z1 = np.concatenate([vx * shrink, vy * shrink])
        z2 = np.clip(l + u2, 0.0, 1.0)
        u1 += dl - z1
        u2 += l - z2
    t2 = time.perf_counter()
    return z2, tg - t0, t1 - tg, t2 - t1


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("--wall", type=int, required=True)
    ap.add_argument("--scene-grid", type=int, required=True)
    ap.add_argument("--measurement", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--iterations", type=int, default=200)
    ap.add_argument("--no-save", action="store_true", help="do not write T.npy (large grids)")
    a = ap.parse_args()
    with open(a.scene, "rb") as f:
        cfg = tomllib.load(f)
    t0 = time.perf_counter()
    T = build(cfg, a.wall, a.scene_grid)
    build_s = time.perf_counter() - t0
    i = np.load(a.measurement)
    rec, gram_s, factor_s, iterate_s = admm(T, i, a.scene_grid, a.scene_grid, a.iterations)
    if not a.no_save:
        np.save(f"{a.out}/T.npy", T)
    np.save(f"{a.out}/recovered.npy", rec)
    with open(f"{a.out}/peer.json", "w") as f:
        json.dump(
            {
                "numpy": np.__version__,
                "shape": list(T.shape),
                "build_seconds": build_s,
                "gram_seconds": gram_s,
                "factor_seconds": factor_s,
                "iterate_seconds": iterate_s,
                "iterations": a.iterations,
            },
            f,
        )


if __name__ == "__main__":
    main()
