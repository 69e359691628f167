#!/usr/bin/env python3
"""Peer reconstruction of Saunders et al.'s chair photo, written for polnlos.

A NumPy port (own code, not a copy) of the authors' published pipeline from
Saunders, Murray-Bruce, Goyal, "Computational periscopy with an ordinary
digital camera", Nature 565, 472-475 (2019), repository
Computational-Periscopy/Ordinary-Camera (simulate_A.m, simulate_block.m,
simulate_occluder.m, reconstruct_tv_it_cbg.m, fig_S9.m), plus the
data-driven variant recommended for polnlos.

  (a) authors: their A (2x2 point sources per block, cos^18 x cos view-angle
      factor with the wall's z reversed as in their code, poly2mask pixel
      convention), their column-major first-difference data term, FISTA with
      backtracking + isotropic TV, their hand-tuned per-channel scale and TV
      weight for the mushroom (fig_S9.m), display = clip(x, 0, 1).
  (b) recommended: exact T (view-angle factor not mirrored, visibility at the
      wall samples), data term ||D i - D T l||^2 with D = vertical+horizontal
      first differences of the 126x126 wall image (the ambient background drops
      out), isotropic TV + l >= 0 solved by ADMM with one Cholesky factor shared
      by the three channels, TV weight per channel by the discrepancy principle
      with the noise level taken from the nonnegative LS residual (lambda -> 0),
      display = per-channel scale mapping the 99th percentile to 255.

Orientation: measurement[r, c] is the wall point x = x(c) ascending with c,
z = z(r) descending with r (row 0 = top, a natural photo of the wall).
truth[r, c] is the monitor block with z = Mon_zdiscr[r] (row 0 = top) and
x = Mon_xdiscr[35 - c] (a viewer facing the monitor has +x on their left).

Usage: python3 peer.py [--data DIR] [--out DIR] [--skip-authors]
"""
import argparse, json, os, time
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
DEFAULT_DATA = os.path.join(HERE, '..', '..', 'tests', 'data', 'saunders-chair')


# ----------------------------------------------------------------- geometry / T
def wall_coords(g):
    n = len(g['wall_vec'])
    wv = np.linspace(-1, 1, n)
    (lx, lz), (sx, sz) = g['FOV_LLCorner_xz'], g['FOV_size_xz']
    return lx + sx * (wv + 1) / 2, (lz + sz * (wv + 1) / 2)[::-1]


def shadow_intervals(src, quads, zrows, D):
    """x-interval of each quad's shadow (convex hull of its corners projected from
    each source onto y = D) on each wall row z. Returns xl, xr of shape (S, Q, R)."""
    s = src[:, None, None, :]
    c = quads[None]
    t = (D - s[..., 1]) / (c[..., 1] - s[..., 1])
    px = s[..., 0] + t * (c[..., 0] - s[..., 0])
    pz = s[..., 2] + t * (c[..., 2] - s[..., 2])
    xl = np.full(px.shape[:2] + (len(zrows),), np.inf)
    xr = -xl
    zz = zrows[None, None, :]
    for i, j in [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]:  # hull cut = all chords
        z0, z1 = pz[..., i, None], pz[..., j, None]
        dz = z1 - z0
        with np.errstate(divide='ignore', invalid='ignore'):
            u = (zz - z0) / dz
        ok = (u >= 0) & (u <= 1) & (dz != 0)
        xi = px[..., i, None] + u * (px[..., j, None] - px[..., i, None])
        xl = np.where(ok, np.minimum(xl, xi), xl)
        xr = np.where(ok, np.maximum(xr, xi), xr)
    return xl, xr


def build_T(g, ndiscr=2, lobe_pow=18, authors=False):
    """T[r*126+c, br*36+bc] = sum over the block's ndiscr^2 point sources of
    (block area / ndiscr^2) * Mz*Mx * D^2 / dist^4 * visibility."""
    D, mon = g['D'], g['monitor']
    R, C = mon['NumBlocks_rows_cols']
    bsx, bsz = mon['IlluminationBlock_Size_xz']
    mx, mz = np.array(mon['Mon_xdiscr']), np.array(mon['Mon_zdiscr'])
    xw, zw = wall_coords(g)
    n = len(xw)
    quads = np.array(g['occluder']['chair_quads_corners'])
    if authors:  # poly2mask samples pixel centres at FOV_LL + k*size/n, k = 1..n
        k = np.arange(1, n + 1)
        xv = g['FOV_LLCorner_xz'][0] + k * g['FOV_size_xz'][0] / n
        zv = (g['FOV_LLCorner_xz'][1] + k * g['FOV_size_xz'][1] / n)[::-1]
        zmm = zw[::-1]  # their ViewingAngleFactor gets wall z reversed
    else:
        xv, zv, zmm = xw, zw, zw
    T = np.zeros((n * n, R * C))
    rows = np.arange(n)
    for r in range(R):
        for c in range(C):
            mc = C - 1 - c
            SX, SZ = np.meshgrid(mx[mc] - np.arange(ndiscr) * bsx / ndiscr,
                                 mz[r] - np.arange(ndiscr) * bsz / ndiscr)
            src = np.stack([SX.ravel(), np.zeros(SX.size), SZ.ravel()], 1)
            Mz = np.cos(np.arctan((mz[r] - bsz / 2 - zmm) / D)) ** lobe_pow
            Mx = np.cos(np.arctan((mx[mc] - bsx / 2 - xw) / D))
            xl, xr = shadow_intervals(src, quads, zv, D)
            c0 = np.searchsorted(xv, xl, 'left')
            c1 = np.maximum(np.searchsorted(xv, xr, 'right'), c0)
            img = np.zeros((n, n))
            for s in range(src.shape[0]):
                d2 = (xw[None, :] - src[s, 0]) ** 2 + (zw[:, None] - src[s, 2]) ** 2 + D * D
                cnt = np.zeros((n, n + 1))
                rr = np.broadcast_to(rows, c0[s].shape).ravel()
                np.add.at(cnt, (rr, c0[s].ravel()), 1)
                np.add.at(cnt, (rr, c1[s].ravel()), -1)
                img += D * D / d2 ** 2 * (np.cumsum(cnt, 1)[:, :n] < 0.5)
            T[:, r * C + c] = (bsx * bsz / ndiscr ** 2 * Mz[:, None] * Mx[None, :] * img).ravel()
    return T


# ------------------------------------------------------------ authors' solver
def _L(p, q):
    a = np.zeros_like(p); b = np.zeros_like(q)
    a[1:] = np.diff(p, axis=0); a[0] = p[0]
    b[:, 1:] = np.diff(q, axis=1); b[:, 0] = q[:, 0]
    return a + b


def _Lt(x):
    p = np.zeros_like(x); q = np.zeros_like(x)
    p[:-1] = -np.diff(x, axis=0); q[:, :-1] = -np.diff(x, axis=1)
    return p, q


def prox_tv(b, lam, tol=1e-6):
    """Beck-Teboulle fast gradient projection for 1/2||x-b||^2 + lam*TV_iso(x)."""
    r = np.zeros_like(b); s = np.zeros_like(b); po = r.copy(); qo = s.copy()
    told, old = 1.0, 0.0
    while True:
        sol = b - lam * _L(r, s)
        tr, ts = _Lt(sol)
        r = r + tr / (8 * lam); s = s + ts / (8 * lam)
        w = np.maximum(1, np.sqrt(r * r + s * s)); p = r / w; q = s / w
        t = (1 + np.sqrt(1 + 4 * told ** 2)) / 2; told = t
        r = p + ((told - 1) / t) * (p - po); s = q + ((told - 1) / t) * (q - qo)
        po, qo = p, q
        cur = 0.5 * np.sum((b - sol) ** 2) + lam * np.sum(np.sqrt(tr ** 2 + ts ** 2))
        if abs(cur - old) / cur < tol:
            return sol
        old = cur


def fista_backtrack(dA, ATA, ATm, meas, lam, x, step=1e-5, maxit=1100, tol=2.4e-6):
    G = lambda v: 0.5 * np.sum((meas - dA @ v.ravel()) ** 2)
    xo, yo, to = x.copy(), x.copy(), 1.0
    for it in range(maxit):
        gr = (ATA @ yo.ravel() - ATm).reshape(x.shape)
        tn = 0.5 * (1 + np.sqrt(1 + 4 * to ** 2))
        while True:
            xn = prox_tv(yo - step * gr, lam * step)
            if G(xn) <= G(yo) + gr.ravel() @ (xn - yo).ravel() + np.sum((xn - yo) ** 2) / (2 * step):
                break
            step *= 0.3
        yn = xn + (to - 1) / tn * (xn - xo)
        if it >= 10 and np.linalg.norm(xn - xo) / xn.size < tol:
            break
        xo, to, yo = xn, tn, yn
        step *= 5
    return xn


def colmajor_diff(M, n=126):
    """Authors' Diff = I - superdiagonal on the column-major vectorised image."""
    F = M.reshape(n, n, -1).transpose(1, 0, 2).reshape(n * n, -1)
    out = F.copy(); out[:-1] -= F[1:]
    return out


def run_authors(T, meas, g, ndiscr=2):
    cs = (1.3438e4, 1.4688e4, 15625)           # fig_S9.m, mushroom (per ndiscr^2)
    reg = (72000000, 79200000, 345600000)      # fig_S9.m, mushroom TV weights
    bsx, bsz = g['monitor']['IlluminationBlock_Size_xz']
    R, C = g['monitor']['NumBlocks_rows_cols']
    dA = colmajor_diff(T * ndiscr ** 2 / (bsx * bsz))  # their A has no area weight
    ATA0 = dA.T @ dA
    x = np.zeros((R, C, 3))
    for ch in range(3):
        s = cs[ch] / ndiscr ** 2
        mv = colmajor_diff(meas[..., ch].reshape(-1, 1))[:, 0]
        ATA, ATm = s * s * ATA0, s * dA.T @ mv
        x0 = np.linalg.solve(ATA, ATm).reshape(R, C)
        x[..., ch] = fista_backtrack(s * dA, ATA, ATm, mv, reg[ch], x0)
    return np.clip(x, 0, 1) * 255


# --------------------------------------------------------- recommended variant
def first_diff_rows(M, n=126):
    """Vertical then horizontal first differences of an n x n image (rows of M)."""
    A = M.reshape(n, n, -1)
    return np.concatenate([(A[1:] - A[:-1]).reshape(-1, M.shape[1]),
                           (A[:, 1:] - A[:, :-1]).reshape(-1, M.shape[1])])


def tv_grad(R, C):
    """Forward differences (vertical block, then horizontal), Neumann boundary."""
    Dv = np.kron(np.eye(R - 1, R, 1) - np.eye(R - 1, R), np.eye(C))
    Dh = np.kron(np.eye(R), np.eye(C - 1, C, 1) - np.eye(C - 1, C))
    return np.vstack([Dv, Dh])


def iso_shrink(v, thr, R, C):
    nv = (R - 1) * C
    a = v[:nv].reshape(R - 1, C, -1); b = v[nv:].reshape(R, C - 1, -1)
    za = np.sign(a) * np.maximum(np.abs(a) - thr, 0); zb = np.sign(b) * np.maximum(np.abs(b) - thr, 0)
    pa, pb = a[:, :C - 1], b[:R - 1]
    mag = np.maximum(np.sqrt(pa ** 2 + pb ** 2), 1e-300)
    k = np.maximum(1 - thr / mag, 0)
    za[:, :C - 1] = pa * k; zb[:R - 1] = pb * k
    return np.concatenate([za.reshape(nv, -1), zb.reshape(-1, a.shape[2])])


def run_recommended(T, meas, g, rho=0.1, it0=150, it=50, nbis=6):
    from scipy.linalg import cho_factor, cho_solve
    R, C = g['monitor']['NumBlocks_rows_cols']
    nb = R * C
    K = first_diff_rows(T); Y = first_diff_rows(meas.reshape(-1, 3))
    M = K.shape[0]
    G = K.T @ K
    sK = np.sqrt(np.linalg.eigvalsh(G)[-1])
    G /= sK ** 2; KtY = K.T @ Y / sK
    # noise level from the unconstrained LS residual, only to normalise units
    cf = cho_factor(G)
    rls = np.sum(Y ** 2, 0) - np.sum(cho_solve(cf, KtY) * KtY, 0)
    sig = np.sqrt(rls / (M - nb))
    KtY /= sig; yy = np.sum(Y ** 2, 0) / sig ** 2
    rss = lambda l: yy - 2 * np.sum(l * KtY, 0) + np.sum(l * (G @ l), 0)
    Dg = tv_grad(R, C)
    cf = cho_factor(G + rho * (Dg.T @ Dg + np.eye(nb)))  # shared by all channels / lambdas

    def admm(lam, iters, st):
        l, z1, u1, z2, u2 = st
        for _ in range(iters):
            l = cho_solve(cf, KtY + rho * (Dg.T @ (z1 - u1) + z2 - u2))
            Dl = Dg @ l
            z1 = iso_shrink(Dl + u1, lam[None, :] / rho, R, C) if np.any(lam > 0) else Dl + u1
            z2 = np.maximum(l + u2, 0)
            u1 = u1 + Dl - z1; u2 = u2 + l - z2
        return z2, (l, z1, u1, z2, u2)

    z = np.zeros((nb, 3))
    x0, st = admm(np.zeros(3), it0, (z, Dg @ z, Dg @ z, z, z))   # nonnegative LS
    target = rss(x0) * M / (M - nb)                                # discrepancy level
    lo, hi = np.full(3, -2.0), np.full(3, 1.0)                     # log10 lambda bracket
    for _ in range(nbis):
        mid = (lo + hi) / 2
        x, st = admm(10 ** mid, it, st)
        big = rss(x) > target
        hi = np.where(big, mid, hi); lo = np.where(big, lo, mid)
    lam = 10 ** ((lo + hi) / 2)
    x, st = admm(lam, it, st)
    x = x.reshape(R, C, 3)
    disp = np.stack([x[..., ch] * 255 / max(np.percentile(x[..., ch], 99), 1e-300)
                     for ch in range(3)], 2)
    return np.clip(disp, 0, 255), lam, x


# ------------------------------------------------------------------- metrics
def zncc(x, t):
    a = x.ravel() - x.mean(); b = t.ravel() - t.mean()
    return float(a @ b / np.sqrt((a @ a) * (b @ b)))


def psnr(x, t):
    return float(10 * np.log10(255.0 ** 2 / np.mean((x - t) ** 2)))


def affine_fit(x, t):
    out = np.empty(t.shape)
    for ch in range(t.shape[2]):
        A = np.stack([x[..., ch].ravel(), np.ones(x[..., ch].size)], 1)
        out[..., ch] = (A @ np.linalg.lstsq(A, t[..., ch].ravel(), rcond=None)[0]).reshape(t.shape[:2])
    return out


def ssim(x, t, k=7):
    """Mean SSIM over channels, k x k uniform window, sample covariance, peak 255."""
    from numpy.lib.stride_tricks import sliding_window_view as sw
    f = lambda a: sw(a, (k, k)).mean(axis=(-1, -2))
    C1, C2, cn = (0.01 * 255) ** 2, (0.03 * 255) ** 2, k * k / (k * k - 1)
    vals = []
    for ch in range(t.shape[2]):
        X, Y = x[..., ch], t[..., ch]
        ux, uy = f(X), f(Y)
        vx, vy, vxy = cn * (f(X * X) - ux * ux), cn * (f(Y * Y) - uy * uy), cn * (f(X * Y) - ux * uy)
        vals.append((((2 * ux * uy + C1) * (2 * vxy + C2)) / ((ux ** 2 + uy ** 2 + C1) * (vx + vy + C2))).mean())
    return float(np.mean(vals))


def report(name, x, t, secs):
    print('%-12s ZNCC %.3f  PSNR raw %.2f dB  PSNR affine %.2f dB  SSIM %.3f  time %.1f s'
          % (name, zncc(x, t), psnr(x, t), psnr(affine_fit(x, t), t), ssim(x, t), secs), flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('data', nargs='?', default=None)
    ap.add_argument('--data', dest='data_flag', default=None)
    ap.add_argument('--out', default=None, help='directory for .npy results')
    ap.add_argument('--skip-authors', action='store_true')
    a = ap.parse_args()
    data = a.data_flag or a.data or DEFAULT_DATA
    g = json.load(open(os.path.join(data, 'geometry.json')))
    meas = np.load(os.path.join(data, 'measurement_rgb.npy'))
    truth = np.load(os.path.join(data, 'truth_rgb.npy')).astype(float)
    out = {}
    if not a.skip_authors:
        t0 = time.time(); Ta = build_T(g, authors=True); x = run_authors(Ta, meas, g)
        report('authors', x, truth, time.time() - t0); out['authors'] = x
    t0 = time.time(); T = build_T(g); tT = time.time() - t0
    x, lam, lraw = run_recommended(T, meas, g)
    report('recommended', x, truth, time.time() - t0)
    print('  T build %.1f s; TV weight per channel (noise units, ||DT|| = 1): %s' % (tT, np.round(lam, 3)))
    out.update(recommended=x, recommended_linear=lraw, T=T)
    if a.out:
        os.makedirs(a.out, exist_ok=True)
        for k, v in out.items():
            np.save(os.path.join(a.out, k + '.npy'), v)


if __name__ == '__main__':
    main()
