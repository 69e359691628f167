"""The client against a real daemon (`polnlos serve` with Aravis's fake
camera on 127.0.0.1, started by tests/daemon/python.rs): captures, a
reconstruction, downloads as arrays, the event stream and errors."""

import queue
import threading

import numpy as np
import pytest

import polnlos


@pytest.fixture(scope="module")
def client(daemon_url):
    return polnlos.Client(daemon_url, timeout=30)


def test_a_capture_reconstructs_and_downloads_as_arrays(client):
    assert client.health()["camera_connected"] is True
    assert "brewster-crossed" in client.scenes()
    light = client.wait(client.capture("brewster-crossed", "A", polarizer_deg=0,
                                       exposure_us=20000, frames=4, dark_frames=2))
    assert light["state"] == "done"
    mean = client.capture_mean(light["id"])
    assert mean.shape == (512, 512) and mean.dtype == np.float64
    assert mean.max() > 0
    rec = client.wait(client.reconstruct("brewster-crossed", [light["id"]], truth="letter"))
    assert rec["state"] == "done"
    image = client.recovered(rec["id"])
    assert image.shape == tuple(polnlos.Scene.load("brewster-crossed").scene_shape)
    assert 0.0 <= image.min() and image.max() <= 1.0
    report = client.report(rec["id"])
    assert report["metrics"]["psnr_db"] > 12, report["metrics"]
    m = client.measurement(rec["id"])
    assert m.shape == (polnlos.Scene.load("brewster-crossed").rows,)


def test_an_imported_measurement_reconstructs_fitted_as_offline(client):
    """A measurement taken elsewhere, imported through the client, is fitted
    (its gain and background unknown) to the numbers of the offline call."""
    scene = polnlos.Scene.load("brewster-crossed")
    truth = polnlos.pattern("letter", scene)
    i, _ = polnlos.simulate(scene, truth, photons=2e4, seed=5)
    photo = 2.0 * i + 0.1
    cap = client.import_capture("brewster-crossed", "A", photo, polarizer_deg=0, name="sim.npy")
    assert cap["state"] == "done" and cap["kind"] == "light"
    assert cap["import"]["format"] == "npy" and cap["import"]["name"] == "sim.npy"
    rec = client.wait(client.reconstruct("brewster-crossed", [cap["id"]]))
    assert rec["state"] == "done", rec
    report = client.report(rec["id"])
    assert report["radiometry"]["mode"] == "fitted" and not report["radiometry"]["given"]
    want, _ = polnlos.reconstruct(scene, photo, radiometry="fitted")
    assert np.max(np.abs(client.recovered(rec["id"]) - want)) <= 1e-9
    # Scored against a truth image (top row first, as polnlos.pattern gives
    # it) to the offline call's numbers.
    scored = client.wait(client.reconstruct("brewster-crossed", [cap["id"]], truth=truth))
    _, offline = polnlos.reconstruct(scene, photo, radiometry="fitted", truth=truth)
    got = client.report(scored["id"])["metrics"]
    assert abs(got["zncc"] - offline["metrics"]["zncc"]) <= 1e-9, (got, offline["metrics"])
    assert got["zncc"] > 0.5
    with pytest.raises(polnlos.DaemonError) as e:
        client.reconstruct("brewster-crossed", [cap["id"]], truth=truth[1:])
    assert e.value.status == 422 and "the scene grid is" in e.value.message
    with pytest.raises(polnlos.DaemonError) as e:
        client.import_capture("brewster-crossed", "A", photo[:-1])
    assert e.value.status == 422 and "[1024]" in e.value.message


def test_a_plan_runs_the_scene_through_the_mount_to_a_reconstruction(client):
    accepted = client.plan("brewster-crossed", exposure_us=20000, frames=2, dark_frames=1,
                           reconstruct={"truth": "letter"})
    plan = client.wait(accepted, timeout=300)
    assert plan["state"] == "done", plan
    assert len(plan["captures"]) == 1, plan
    assert plan["reconstruction"] is not None, plan
    rec = client.wait({"job": f"reconstruction-{plan['reconstruction']}"})
    assert rec["state"] == "done"
    assert client.recovered(plan["reconstruction"]).shape == (8, 8)
    assert client.get_plan(accepted["id"])["id"] == accepted["id"]


def test_events_arrive_as_dicts_while_a_capture_runs(client):
    seen = queue.Queue()

    def listen():
        try:
            for e in client.events(timeout=30):
                seen.put(e)
        except Exception as e:  # the stream's end when the test is over
            seen.put(e)

    threading.Thread(target=listen, daemon=True).start()
    accepted = None
    job = None
    for _ in range(300):
        if accepted is None:
            # Subscribe first: the capture's events come after.
            threading.Event().wait(0.3)
            accepted = client.capture("brewster-crossed", "A", polarizer_deg=0,
                                      exposure_us=10000, frames=1)
            job = accepted["job"]
        e = seen.get(timeout=30)
        assert isinstance(e, dict), e
        if e.get("job") == job and e.get("state") == "done":
            break
    else:
        pytest.fail(f"no 'done' event for {job}")


def test_errors_carry_the_daemons_status_and_sentence(client):
    with pytest.raises(polnlos.DaemonError) as e:
        client.capture("brewster-crossed", "Q", polarizer_deg=0, exposure_us=1000, frames=1)
    assert e.value.status in (404, 422)
    assert "Q" in e.value.message
    with pytest.raises(polnlos.DaemonError) as e:
        client.get_capture(999999)
    assert e.value.status == 404
    with pytest.raises(polnlos.PolnlosError, match="cannot reach"):
        polnlos.Client("http://127.0.0.1:9", timeout=2).health()


def test_the_live_view_gives_results_and_stops(client):
    """Live view through the client: results arrive, each solving a full
    window, the image downloads, and stopping frees the camera."""
    import time
    started = client.live_start("brewster-crossed", "A", polarizer_deg=0, exposure_us=20000,
                                frames=4, dark_frames=2, progressive={"truth": "letter"},
                                record=6)
    assert started["state"] in ("starting", "running"), started
    assert started["recording"]["of"] == 6, started
    end = time.monotonic() + 30
    state = client.live()
    while state["results"] < 3 or state["recording"]["state"] != "done":
        assert time.monotonic() < end, state
        time.sleep(0.1)
        state = client.live()
    assert state["last"]["frames"] == 4, state
    assert state["last"]["psnr_db"] > 10, state
    assert state["recording"]["frames"] == 6, state
    recorded = client.get_capture(state["recording"]["capture"])
    assert recorded["state"] == "done" and recorded["frames"] == 6, recorded
    assert client.live_image()[1:4] == b"PNG"
    stopped = client.live_stop()
    assert stopped["state"] == "off" and stopped["results"] >= 3, stopped
    assert client.live()["state"] == "off"
    # Without difference mode nothing is tracked; with it every result has
    # a row (this bench's scene stands still: its centroid may be None).
    assert client.live_track() == []
    client.live_start("brewster-crossed", "A", polarizer_deg=0, exposure_us=20000,
                      frames=4, dark_frames=2, difference={"background_s": 2})
    end = time.monotonic() + 30
    while client.live()["results"] < 3:
        assert time.monotonic() < end, client.live()
        time.sleep(0.1)
    state = client.live()
    assert state["difference_background_s"] == 2, state
    track = client.live_track()
    assert len(track) >= 3, track
    assert set(track[0]) == {"time_s", "u_m", "v_m", "sigma_u_m", "sigma_v_m"}, track
    assert all(abs(row["time_s"] - time.time()) < 60 for row in track), track
    client.live_stop()
    assert len(client.live_track()) >= 3, "the track is kept after the session stops"
    # A photo scene's radiometry: each window's gain and background fitted.
    client.live_start("brewster-crossed", "A", polarizer_deg=0, exposure_us=20000,
                      frames=4, dark_frames=0, progressive={"truth": "letter"},
                      radiometry="fitted")
    end = time.monotonic() + 30
    while client.live()["results"] < 3:
        assert time.monotonic() < end, client.live()
        time.sleep(0.1)
    state = client.live()
    assert state["radiometry"]["mode"] == "fitted", state
    fitted = state["last"]["fitted"]
    assert fitted["gain"][0] > 0 and fitted["background"][0][0] > 0, state
    assert state["last"]["psnr_db"] > 10, state
    client.live_stop()



def test_a_target_capture_calibrates_the_pose_and_colour_needs_a_light_capture(client):
    """The calibration doors: a target capture fits the pose's homography to
    a fraction of a pixel; a colour calibration of a dark capture is refused
    with the daemon's sentence; the calibrations list the scene's gain."""
    target = client.wait(client.capture("brewster-crossed", "A", kind="target", polarizer_deg=0,
                                        exposure_us=20000, frames=4, dark_frames=2))
    assert target["state"] == "done", target
    fit = client.calibrate(target["id"])
    assert fit["pose"] == "A" and fit["dots"] >= 9, (fit["dots"], fit["rms_px"], fit["warnings"])
    assert fit["rms_px"] < 0.2, (fit["dots"], fit["rms_px"], fit["warnings"])
    assert "homography" in fit["scene_toml"]
    dark = client.wait(client.capture("brewster-crossed", "A", kind="dark", polarizer_deg=0,
                                      exposure_us=20000, frames=2))
    with pytest.raises(polnlos.DaemonError) as e:
        client.calibrate_colour(dark["id"])
    assert e.value.status == 422
    assert "white or grey field" in e.value.message, e.value.message
    listed = client.calibrations()
    assert any(g["scene"] == "brewster-crossed" and g["gain"] > 0 for g in listed["radiometric"]), listed



def test_a_scene_is_added_replaced_and_deleted_without_a_restart(client):
    import pathlib
    text = (pathlib.Path(__file__).parents[2] / "config/scenes/brewster-crossed.toml").read_text()
    added = client.add_scene("from-python", "# mine\n" + text)
    assert added == {"name": "from-python", "origin": "posted", "error": None, "fitted_by": None}
    assert "from-python" in client.scenes()
    with pytest.raises(polnlos.DaemonError) as e:
        client.add_scene("from-python", text)
    assert e.value.status == 409
    with pytest.raises(polnlos.DaemonError) as e:
        client.replace_scene("from-python", "[wall]\nsize = [0.3,\n")
    assert e.value.status == 422 and "line 2" in e.value.message
    replaced = client.replace_scene("from-python", text.replace("grid = [8, 8]", "grid = [4, 4]", 1))
    assert replaced["origin"] == "posted"
    client.delete_scene("from-python")
    assert "from-python" not in client.scenes()
    listed = {s["name"]: s for s in client.scene_list()}
    assert listed["brewster-crossed"]["origin"] == "built-in"


def test_a_scene_calibration_places_the_bench_for_later_reconstructions(client):
    """A photo of a bench whose occluder stands 8 mm along x and -6 mm along z
    off its file, imported and fitted through the client: the fitted
    offsets cover the truth, and the next reconstruction uses them."""
    import pathlib
    text = (pathlib.Path(__file__).parents[2] / "config/scenes/occluder-nopol.toml").read_text()
    written = "center = [-0.187, 0.0, 0.125]"
    assert written in text
    bench = polnlos.Scene.from_toml(text.replace(written, "center = [-0.179, 0.0, 0.119]"))
    client.add_scene("nopol-python", text)
    try:
        truth = polnlos.pattern("letter", bench)
        photo, _ = polnlos.simulate(bench, truth, photons=1e5, seed=3)
        cap = client.import_capture("nopol-python", "A", photo, name="sim.npy")
        before = client.report(client.wait(client.reconstruct("nopol-python", [cap["id"]], truth=truth))["id"])
        assert before["geometry"] == "as written"
        free = ["occluder-x", "occluder-y", "occluder-z"]
        fit = client.calibrate_scene("nopol-python", [cap["id"]], free=free, known=truth)
        assert fit["state"] == "done", fit
        for f, want in zip(fit["fit"]["fitted"], [0.008, 0.0, -0.006]):
            assert abs(f["offset"] - want) < 2 * f["uncertainty"], fit["fit"]["fitted"]
        after = client.report(client.wait(client.reconstruct("nopol-python", [cap["id"]], truth=truth))["id"])
        assert after["geometry"] == f"fitted by scene calibration {fit['id']}"
        assert after["metrics"]["zncc"] > before["metrics"]["zncc"] + 0.01, (before["metrics"], after["metrics"])
        assert fit["id"] in [c["id"] for c in client.scene_calibrations()]
        with pytest.raises(polnlos.DaemonError) as e:
            client.calibrate_scene("nopol-python", [cap["id"]], free=["occluder-w"])
        assert e.value.status == 422 and "occluder-yaw" in e.value.message
        client.delete_scene_calibration(fit["id"])
        listed = {s["name"]: s for s in client.scene_list()}
        assert listed["nopol-python"]["fitted_by"] is None
    finally:
        client.delete_scene("nopol-python")
