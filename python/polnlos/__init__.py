"""polnlos from Python: the numeric core with NumPy in and out, and a client
for the daemon.

The core functions call the very Rust functions the `polnlos` CLI calls
(`transport`, `cond`, `simulate`, `measure`, `reconstruct`), so a script and
the CLI agree to the last bit; the heavy calls release the GIL.

    import polnlos
    scene = polnlos.Scene.load("brewster-crossed-3x3")
    T = scene.transport()                       # (rows, cols) float64
    truth = polnlos.pattern("letter", scene)
    i, info = polnlos.simulate(scene, truth, photons=2e4, seed=1)
    image, report = polnlos.reconstruct(scene, i, lam=1e-3)
"""

from __future__ import annotations

import warnings as _warnings
import typing as _t

import numpy as _np

from ._polnlos import (  # noqa: F401  (the public names)
    SOLVERS,
    PolnlosError,
    Scene,
    SceneError,
    builtin_scenes,
    decode_tiff,
    pattern,
)
from . import _polnlos
from .client import Client, DaemonError  # noqa: F401

__all__ = [
    "SOLVERS",
    "Client",
    "DaemonError",
    "PolnlosError",
    "Scene",
    "SceneError",
    "builtin_scenes",
    "cond",
    "decode_tiff",
    "measure",
    "pattern",
    "reconstruct",
    "simulate",
]

__version__ = "0.1.0"


def cond(T: _t.Union[_np.ndarray, Scene]) -> dict:
    """Singular values, condition number kappa and numerical rank of T (or of
    a scene's T), as `polnlos cond --json` reports them."""
    if isinstance(T, Scene):
        T = T.transport()
    return _polnlos.cond(_np.ascontiguousarray(T, dtype=_np.float64))


def _f64(a: _t.Any) -> _t.Optional[_np.ndarray]:
    """`a` as a C-contiguous float64 array: no copy when it is one already."""
    return None if a is None else _np.ascontiguousarray(a, dtype=_np.float64)


def simulate(scene: Scene, truth: _t.Any, photons: _t.Optional[float] = None,
             read_noise: _t.Optional[float] = None, bits: _t.Optional[int] = None,
             seed: _t.Optional[int] = None) -> tuple:
    """A simulated measurement of `truth` (radiance in [0, 1] on the scene
    grid) through the scene's T and a camera, as `polnlos simulate`: returns
    `(measurement, info)`; `info` holds the camera model, `electrons_per_unit`,
    `units_per_dn` and the model's `variance` of each value (for
    `reconstruct(..., variance=info["variance"])`). Defaults are the CLI's."""
    kw = {k: v for k, v in dict(photons=photons, read_noise=read_noise, bits=bits,
                                seed=seed).items() if v is not None}
    return _polnlos.simulate(scene, _f64(truth), **kw)


def reconstruct(scene: Scene, measurement: _t.Any, lam: _t.Optional[float] = None,
                variance: _t.Any = None, solver: str = "admm-tv", truth: _t.Any = None,
                max_iter: _t.Optional[int] = None, full_spectrum: bool = False,
                radiometry: str = "calibrated") -> tuple:
    """The hidden scene from `measurement`, as `polnlos reconstruct`: returns
    `(image, report)`, the image on the scene grid and report.json as a dict.

    `radiometry="fitted"` is `polnlos reconstruct --photo` (and the daemon's
    fitted reconstruction): a photo whose gain and ambient light are unknown,
    `measurement` `[rows]` or `[rows, C]` (one column per colour channel),
    gain, background and λ fitted from it (docs/realphoto.md); `variance`,
    `solver` and `full_spectrum` do not apply. The default, "calibrated",
    reads the measurement in units of T l.

    `lam` None chooses λ from the noise (the resolved-discrepancy rule): from
    `variance` (one value per measurement value) when given, else estimated
    from the measurement. With the noise known, the sampling keys the scene
    file leaves out are chosen from it (`report["model"]`). `solver` is one
    of `polnlos.SOLVERS` (the library's registered solvers, default
    admm-tv)."""
    if radiometry == "fitted":
        if variance is not None or solver != "admm-tv" or full_spectrum:
            raise PolnlosError("radiometry=\"fitted\" fits its own noise and solves with admm-tv: "
                               "leave out variance, solver and full_spectrum")
        return _polnlos.reconstruct_photo(scene, _f64(measurement), lam=lam, truth=_f64(truth),
                                          max_iter=max_iter)
    if radiometry != "calibrated":
        raise PolnlosError(f"radiometry {radiometry!r} is neither \"calibrated\" nor \"fitted\"")
    return _polnlos.reconstruct(scene, _f64(measurement), lam=lam, variance=_f64(variance),
                                solver=solver, truth=_f64(truth), max_iter=max_iter,
                                full_spectrum=full_spectrum)


def _per_capture(value: _t.Any, k: int, n: int, name: str) -> _t.Any:
    """One value for all captures, or the k-th of one per capture."""
    if isinstance(value, (list, tuple)):
        if len(value) == 1:
            return value[0]
        if len(value) != n:
            raise ValueError(
                f"{len(value)} values of {name} for {n} captures; "
                "give one for all or one per capture"
            )
        return value[k]
    return value


def measure(
    scene: Scene,
    frames: _t.Union[_np.ndarray, _t.Sequence[_np.ndarray]],
    pose: _t.Union[str, _t.Sequence[str]],
    angle: _t.Union[float, str, _t.Sequence[_t.Union[float, str]]],
    exposure_us: _t.Union[float, _t.Sequence[float]],
    dark: _t.Optional[_t.Union[_np.ndarray, _t.Sequence[_np.ndarray]]] = None,
    full_scale: _t.Optional[_t.Union[float, _t.Sequence[float]]] = None,
    gain: _t.Optional[float] = None,
    raw: bool = False,
) -> tuple:
    """Camera frames to the measurement `i` and its variance, as `polnlos
    measure` computes them: every pixel of each wall element, footprint
    weighted (MODEL.md revision 3).

    `frames` is one capture's frames, a (frames, height, width) or
    (height, width) array of uint8, uint16, float32 or float64 DN, or a list
    of them, one per capture; `pose`, `angle` (degrees from crossed, "none",
    or "mosaic" for a polarization camera's four blocks), `exposure_us`,
    `dark` and `full_scale` are given once for all captures or once per
    capture. Returns `(i, variance)`; the variance is None when a capture
    has fewer than 2 frames. Warnings (no dark subtraction, estimated units)
    are issued as Python warnings.
    """
    many = isinstance(frames, (list, tuple))
    stacks = list(frames) if many else [frames]
    n = len(stacks)
    darks = dark if (many and isinstance(dark, (list, tuple))) else [dark]
    captures = []
    for k, f in enumerate(stacks):
        d = _per_capture(darks, k, n, "dark")
        captures.append(
            {
                "frames": _np.asarray(f),
                "pose": _per_capture(pose, k, n, "pose"),
                "angle": _per_capture(angle, k, n, "angle"),
                "exposure_us": float(_per_capture(exposure_us, k, n, "exposure_us")),
                "dark": None if d is None else _np.asarray(d),
                "full_scale": _per_capture(full_scale, k, n, "full_scale"),
            }
        )
    i, variance, info = _polnlos.measure_captures(scene, captures, gain=gain, raw=raw)
    for w in info["warnings"]:
        _warnings.warn(w, stacklevel=2)
    return i, variance
