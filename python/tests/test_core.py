"""The bindings against the CLI they share their code with: the same T, the
same simulation, measurement and reconstruction, to the last bits; errors
that name the key; the GIL released around the heavy calls."""

import json
import struct
import threading
import time

import numpy as np
import pytest

import polnlos

SCENE = "brewster-crossed-3x3"


def test_a_scene_shows_its_grids_blocks_and_poses():
    s = polnlos.Scene.load("brewster-multi-3x3")
    assert s.name == "brewster-multi-3x3"
    assert s.scene_shape == (3, 3)
    assert s.wall_shape == (32, 32)
    assert s.poses == ["B", "C"]
    assert len(s.blocks) * 32 * 32 == s.rows
    assert s.cols == 9
    assert SCENE in polnlos.builtin_scenes()


def test_transport_equals_the_cli_to_1e_12(cli, tmp_path):
    cli("transport", SCENE, "--out", tmp_path / "T.npy")
    want = np.load(tmp_path / "T.npy")
    got = polnlos.Scene.load(SCENE).transport()
    assert got.shape == want.shape == (1024, 9)
    assert got.dtype == np.float64
    assert np.max(np.abs(got - want)) <= 1e-12 * np.max(np.abs(want))


def test_cond_equals_the_cli(cli):
    want = json.loads(cli("cond", SCENE, "--json").stdout)
    got = polnlos.cond(polnlos.Scene.load(SCENE))
    assert got["rank"] == want["rank"]
    np.testing.assert_allclose(got["singular_values"], want["singular_values"], rtol=1e-10)
    np.testing.assert_allclose(got["kappa"], want["kappa"], rtol=1e-8)


def _simulated(cli, tmp_path, scene=SCENE, seed=3):
    s = polnlos.Scene.load(scene)
    truth = polnlos.pattern("letter", s)
    np.save(tmp_path / "truth.npy", truth)
    cli("simulate", scene, "--truth", tmp_path / "truth.npy", "--out", tmp_path / "sim",
        "--photons", 20000, "--seed", seed)
    return s, truth, np.load(tmp_path / "sim" / "measurement.npy")


def test_simulate_equals_the_cli_seed_for_seed(cli, tmp_path):
    s, truth, want = _simulated(cli, tmp_path)
    got, info = polnlos.simulate(s, truth, photons=20000, seed=3)
    np.testing.assert_array_equal(got, want)
    other, _ = polnlos.simulate(s, truth, photons=20000, seed=4)
    assert np.any(other != want)
    meta = json.loads((tmp_path / "sim" / "simulate.json").read_text())
    assert info["electrons_per_unit"] == meta["electrons_per_unit"]


def _untimed(v):
    """A report without its timings (the only values two runs may differ in)."""
    if isinstance(v, dict):
        return {k: _untimed(x) for k, x in v.items() if not k.endswith("_seconds")}
    if isinstance(v, list):
        return [_untimed(x) for x in v]
    return v


@pytest.mark.parametrize("lam", ["1e-3", "1e-9"])
def test_reconstruct_equals_the_cli_to_1e_9(cli, tmp_path, lam):
    s, truth, i = _simulated(cli, tmp_path)
    cli("reconstruct", SCENE, "--measurement", tmp_path / "sim" / "measurement.npy",
        "--lambda", lam, "--truth", tmp_path / "truth.npy", "--out", tmp_path / "rec")
    want = np.load(tmp_path / "rec" / "recovered.npy")
    image, report = polnlos.reconstruct(s, i, lam=float(lam), truth=truth)
    assert image.shape == (3, 3)
    assert np.max(np.abs(image - want)) <= 1e-9
    want_report = json.loads((tmp_path / "rec" / "report.json").read_text())
    # The same report but for timings; the scene is named as the CLI names it.
    assert _untimed(report) == _untimed(want_report)
    assert report["solver"]["lambda"] == float(lam)
    if lam == "1e-9":
        assert np.ptp(image) > 0.1  # not a flat image: the comparison means something


@pytest.mark.parametrize("solver", polnlos.SOLVERS)
def test_every_registered_solver_runs_from_python(cli, tmp_path, solver):
    # polnlos.SOLVERS is the library's registry: a new solver is tested here
    # with no edit. Each at its own default λ (from the noise for TV).
    s, truth, i = _simulated(cli, tmp_path)
    image, report = polnlos.reconstruct(s, i, solver=solver, truth=truth)
    assert report["solver"]["solver"] == solver
    assert image.shape == (3, 3)
    assert np.all((image >= 0) & (image <= 1))
    assert report["metrics"]["psnr_db"] > 5


def test_an_automatic_lambda_from_a_variance_is_reported(cli, tmp_path):
    s, truth, i = _simulated(cli, tmp_path)
    var = np.full(i.shape, 1e-6)
    image, report = polnlos.reconstruct(s, i, variance=var)
    assert report["lambda_choice"]["noise"] == "frame-variance"
    assert report["solver"]["lambda"] == report["lambda_choice"]["lambda"]


def _tiff(pages):
    """A baseline multi-page 16-bit grey TIFF (uncompressed, one strip a page)."""
    n, h, w = pages.shape
    out = bytearray(b"II*\x00")
    entries = 9
    offset = 8
    out += struct.pack("<I", offset)
    for k in range(n):
        data_at = offset + 2 + entries * 12 + 4
        nxt = data_at + h * w * 2 if k + 1 < n else 0
        tags = [(256, 4, w), (257, 4, h), (258, 3, 16), (259, 3, 1), (262, 3, 1),
                (273, 4, data_at), (277, 3, 1), (278, 4, h), (279, 4, h * w * 2)]
        out += struct.pack("<H", entries)
        for tag, typ, val in tags:
            out += struct.pack("<HHII", tag, typ, 1, val) if typ == 4 else struct.pack("<HHIHH", tag, typ, 1, val, 0)
        out += struct.pack("<I", nxt)
        out += pages[k].astype("<u2").tobytes()
        offset = nxt
    return bytes(out)


def test_measure_equals_the_cli_and_takes_every_pixel(cli, tmp_path):
    rng = np.random.default_rng(5)
    frames = rng.normal(8000, 300, size=(4, 512, 512)).clip(0, 65535).astype(np.uint16)
    dark = rng.normal(1000, 50, size=(2, 512, 512)).clip(0, 65535).astype(np.uint16)
    (tmp_path / "f.tiff").write_bytes(_tiff(frames))
    (tmp_path / "d.tiff").write_bytes(_tiff(dark))
    mean, full = polnlos.decode_tiff((tmp_path / "f.tiff").read_bytes())
    np.testing.assert_allclose(mean, frames.mean(axis=0), rtol=1e-12)
    assert full == 65535
    cli("measure", SCENE, "--frames", tmp_path / "f.tiff", "--dark", tmp_path / "d.tiff",
        "--pose", "A", "--angle", "0", "--exposure-us", 20000, "--gain", 0.5, "--out", tmp_path / "i.npy")
    want = np.load(tmp_path / "i.npy")
    want_var = np.load(tmp_path / "i.variance.npy")
    i, var = polnlos.measure(polnlos.Scene.load(SCENE), frames, pose="A", angle=0,
                             exposure_us=20000, dark=dark, gain=0.5)
    np.testing.assert_allclose(i, want, rtol=1e-12, atol=0)
    np.testing.assert_allclose(var, want_var, rtol=1e-12, atol=0)
    # A flat frame measures flat: (8000 - 1000) / 65535 / 20000 us / gain.
    assert np.median(i) == pytest.approx(7000 / 65535 / 20000 / 0.5, rel=0.01)


def test_a_mosaic_frame_measures_to_its_four_blocks_in_order():
    s = polnlos.Scene.load("brewster-mosaic-3x3")
    frame = np.zeros((2, 512, 512), dtype=np.uint16)
    # Sony Polarsens: 90 45 / 135 0 in each 2x2 cell (rows, then columns).
    for (dy, dx), v in {(1, 1): 100, (0, 1): 450, (0, 0): 900, (1, 0): 1350}.items():
        frame[:, dy::2, dx::2] = v
    with pytest.warns(UserWarning, match="no dark subtraction"):
        i, _ = polnlos.measure(s, frame, pose="A", angle="mosaic", exposure_us=1, raw=True)
    blocks = i.reshape(4, -1)
    assert s.blocks[0].endswith("mosaic0") and s.blocks[3].endswith("mosaic135")
    medians = [np.median(b) * 65535 for b in blocks]
    np.testing.assert_allclose(medians, [100, 450, 900, 1350], rtol=1e-9)


def test_errors_name_what_was_wrong(tmp_path):
    bad = tmp_path / "bad.toml"
    text = open_builtin_text().replace("roughness = 0.3", "roughness = -2")
    bad.write_text(text)
    with pytest.raises(polnlos.SceneError, match="roughness"):
        polnlos.Scene.load(str(bad))
    with pytest.raises(polnlos.SceneError, match="no-such-scene"):
        polnlos.Scene.load("no-such-scene")
    s = polnlos.Scene.load(SCENE)
    with pytest.raises(polnlos.PolnlosError, match="1024 rows"):
        polnlos.reconstruct(s, np.zeros(10), lam=1e-3)
    with pytest.raises(ValueError, match="solver"):
        polnlos.reconstruct(s, np.zeros(1024), solver="magic")
    with pytest.raises(ValueError, match=r"\(3, 3\)"):
        polnlos.simulate(s, np.zeros((4, 4)))
    with pytest.raises(polnlos.PolnlosError, match="Z"):
        polnlos.measure(s, np.zeros((2, 512, 512), np.uint16), pose="Z", angle=0, exposure_us=10)
    with pytest.raises(ValueError, match="mosaic"):
        polnlos.measure(s, np.zeros((2, 512, 512), np.uint16), pose="A", angle="sideways", exposure_us=10)
    with pytest.raises(ValueError, match="full_scale"):
        polnlos.measure(s, np.zeros((2, 512, 512)), pose="A", angle=0, exposure_us=10)


def open_builtin_text():
    import pathlib
    root = pathlib.Path(__file__).resolve().parents[2]
    return (root / "config" / "scenes" / f"{SCENE}.toml").read_text()


def test_the_gil_is_released_while_rust_works():
    T = np.random.default_rng(1).normal(size=(1500, 600))
    done = threading.Event()
    ticks = []

    def svd():
        polnlos.cond(T)
        done.set()

    t = threading.Thread(target=svd)
    start = time.perf_counter()
    t.start()
    while not done.is_set():
        ticks.append(time.perf_counter())
        time.sleep(0.001)
    t.join()
    took = time.perf_counter() - start
    # The main thread kept running while Rust took the SVD (a held GIL
    # would leave it a tick or two).
    assert took > 0.05, took
    assert len(ticks) > 20, (len(ticks), took)


def test_the_namespace_holds_polnlos_names_not_typing_helpers():
    """`polnlos.<tab>` shows the package's own names, not typing's."""
    assert not {"Any", "Optional", "Sequence", "Union"} & set(dir(polnlos))
    assert {"reconstruct", "simulate", "Client"} <= set(dir(polnlos))


def test_a_fitted_reconstruction_equals_the_cli_photo_mode_to_1e_9(cli, tmp_path):
    """radiometry="fitted" is `polnlos reconstruct --photo`: gain, ambient
    light and lambda from the photo itself, the same numbers."""
    scene = polnlos.Scene.load("brewster-crossed")
    truth = polnlos.pattern("letter", scene)
    i, _ = polnlos.simulate(scene, truth, photons=2e4, seed=3)
    photo = 3.0 * i + 0.25
    np.save(tmp_path / "photo.npy", photo)
    cli("reconstruct", "brewster-crossed", "--photo", "--measurement", tmp_path / "photo.npy",
        "--out", tmp_path / "rec")
    want = np.load(tmp_path / "rec" / "recovered.npy")
    image, report = polnlos.reconstruct(scene, photo, radiometry="fitted")
    assert report["radiometry"] == {"mode": "fitted", "given": True,
                                    "reason": 'asked for (radiometry="fitted")'}
    assert image.shape == tuple(scene.scene_shape)
    assert np.max(np.abs(image - want.reshape(image.shape))) <= 1e-9
    with pytest.raises(polnlos.PolnlosError, match="admm-tv"):
        polnlos.reconstruct(scene, photo, radiometry="fitted", solver="lsq")
