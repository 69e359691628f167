"""A client for the polnlos daemon's HTTP API (`polnlos serve`).

Thin over the API: request bodies are the API's own fields (see the daemon's
/api page), answers are the API's JSON as dicts, and downloads come back as
NumPy arrays. Standard library only.

    c = polnlos.Client("http://127.0.0.1:8470")
    cap = c.wait(c.capture("brewster-crossed", "A", polarizer_deg=0,
                           exposure_us=20000, frames=4))
    rec = c.wait(c.reconstruct("brewster-crossed", [cap["id"]]))
    image = c.recovered(rec["id"])
"""

from __future__ import annotations

import io
import json
import time
import urllib.error
import urllib.request
from typing import Any, Dict, Iterator, List, Optional

import numpy as np

from ._polnlos import PolnlosError, decode_tiff

# States after which a job or plan changes no more (a plan waiting for the
# operator is not one: `wait` returns there too, so the caller can continue it).
_FINAL = {"done", "failed", "cancelled", "interrupted"}


class DaemonError(PolnlosError):
    """An answer other than 2xx: `status` (HTTP), `code` (`invalid`,
    `not_found`, ...) and the daemon's sentence saying what was wrong."""

    def __init__(self, status: int, code: str, message: str, path: str):
        super().__init__(f"{path}: {status} {code}: {message}")
        self.status = status
        self.code = code
        self.message = message
        self.path = path


class Client:
    """The daemon at `url`, with its bearer `token` when it wants one."""

    def __init__(self, url: str = "http://127.0.0.1:8470", token: Optional[str] = None,
                 timeout: float = 30.0):
        self.url = url.rstrip("/")
        self.token = token
        self.timeout = timeout

    # -- transport ---------------------------------------------------------

    def _request(self, method: str, path: str, body: Any = None,
                 timeout: Optional[float] = None, raw: Optional[bytes] = None,
                 content_type: str = "application/octet-stream"):
        data = None
        headers = {"Accept": "application/json"}
        if body is not None:
            data = json.dumps(body).encode()
            headers["Content-Type"] = "application/json"
        if raw is not None:
            data = raw
            headers["Content-Type"] = content_type
        if self.token:
            headers["Authorization"] = f"Bearer {self.token}"
        req = urllib.request.Request(self.url + path, data=data, method=method, headers=headers)
        try:
            return urllib.request.urlopen(req, timeout=timeout or self.timeout)
        except urllib.error.HTTPError as e:
            raw = e.read()
            try:
                err = json.loads(raw)
                code, message = err.get("error", "error"), err.get("detail", "")
            except ValueError:
                code, message = "error", raw.decode(errors="replace")
            raise DaemonError(e.code, code, message, f"{method} {path}") from None
        except urllib.error.URLError as e:
            raise PolnlosError(f"{method} {path}: cannot reach the daemon at {self.url} ({e.reason}); "
                               "is `polnlos serve` running?") from None

    def _json(self, method: str, path: str, body: Any = None) -> Any:
        with self._request(method, path, body) as r:
            return json.loads(r.read())

    def _bytes(self, path: str) -> bytes:
        with self._request("GET", path) as r:
            return r.read()

    # -- the daemon --------------------------------------------------------

    def health(self) -> Dict[str, Any]:
        """Liveness, the camera's state and the queues."""
        return self._json("GET", "/health")

    def camera(self) -> Dict[str, Any]:
        """The camera: model, sensor, settings, counters."""
        return self._json("GET", "/camera")

    def scenes(self) -> List[str]:
        """The names of the scenes the daemon serves."""
        return [s["name"] for s in self.scene_list() if s.get("error") is None]

    def scene_list(self) -> List[Dict[str, Any]]:
        """Every scene (`GET /scenes`): `name`, `origin` (`built-in`,
        `file`, `posted`) and `error`, why a file does not load (None when
        it serves)."""
        return self._json("GET", "/scenes")

    def _scene_file(self, method: str, path: str, toml_text: str) -> Dict[str, Any]:
        with self._request(method, path, raw=toml_text.encode(),
                           content_type="application/toml") as r:
            return json.loads(r.read())

    def add_scene(self, name: str, toml_text: str) -> Dict[str, Any]:
        """Adds scene `name` from the text of its file (`POST /scenes`),
        served at once without a restart; relative mesh paths are read from
        the data directory's `scenes/`. A bad file raises `DaemonError`
        (422) naming its line."""
        import urllib.parse
        query = urllib.parse.urlencode({"name": name})
        return self._scene_file("POST", f"/scenes?{query}", toml_text)

    def replace_scene(self, name: str, toml_text: str) -> Dict[str, Any]:
        """Replaces scene `name` (`PUT /scenes/{name}`), e.g. with a
        calibration's `scene_toml`; a job that started before keeps the old
        scene."""
        import urllib.parse
        return self._scene_file("PUT", f"/scenes/{urllib.parse.quote(name, safe='')}", toml_text)

    def delete_scene(self, name: str) -> None:
        """Deletes posted scene `name` (`DELETE /scenes/{name}`)."""
        import urllib.parse
        with self._request("DELETE", f"/scenes/{urllib.parse.quote(name, safe='')}"):
            pass

    # -- captures ------------------------------------------------------------

    def capture(self, scene: str, pose: str, **fields: Any) -> Dict[str, Any]:
        """Queues a capture (`POST /captures`): `polarizer_deg`, `exposure_us`,
        `frames`, `kind` ("light" or "dark") and the API's other fields.
        Returns the accepted job (`id`, `job`, `state`)."""
        return self._json("POST", "/captures", {"scene": scene, "pose": pose, **fields})

    def captures(self) -> List[Dict[str, Any]]:
        """The newest captures (`GET /captures`)."""
        return self._json("GET", "/captures")

    def get_capture(self, capture_id: int) -> Dict[str, Any]:
        """One capture's record."""
        return self._json("GET", f"/captures/{int(capture_id)}")

    def capture_mean(self, capture_id: int) -> np.ndarray:
        """A capture's mean frame (DN, dark-subtracted when it has a dark)."""
        mean, _ = decode_tiff(self._bytes(f"/captures/{int(capture_id)}/mean.tiff"))
        return mean

    def import_capture(self, scene: str, pose: str, data: Any,
                       polarizer_deg: Optional[float] = None, bayer: Optional[str] = None,
                       name: Optional[str] = None) -> Dict[str, Any]:
        """Imports a measurement or photo taken elsewhere as a done capture of
        `pose` (`POST /captures/import`): `data` is a NumPy array (`[rows]` or
        `[rows, C]` in the scene's row order, sent as .npy), the bytes of a
        .npy, TIFF or PNG, or a path to one. `bayer` names a raw colour frame's
        pattern (RG, GR, GB, BG). Returns the capture's record; reconstruct it
        with `reconstruct(scene, [record["id"]])` (its gain and background are
        fitted)."""
        import os
        import urllib.parse
        if isinstance(data, np.ndarray):
            buf = io.BytesIO()
            np.save(buf, np.ascontiguousarray(data, dtype=np.float64))
            raw = buf.getvalue()
        elif isinstance(data, (bytes, bytearray)):
            raw = bytes(data)
        else:
            path = os.fspath(data)
            with open(path, "rb") as f:
                raw = f.read()
            name = name or os.path.basename(path)
        query = {"scene": scene, "pose": pose}
        for k, v in (("polarizer_deg", polarizer_deg), ("bayer", bayer), ("name", name)):
            if v is not None:
                query[k] = v
        path = "/captures/import?" + urllib.parse.urlencode(query)
        with self._request("POST", path, raw=raw, timeout=max(self.timeout, 120.0)) as r:
            return json.loads(r.read())

    def delete_capture(self, capture_id: int) -> Dict[str, Any]:
        """Deletes a finished capture, its row and its files."""
        return self._json("DELETE", f"/captures/{int(capture_id)}")

    # -- reconstructions -----------------------------------------------------

    def reconstruct(self, scene: str, captures: List[int], **fields: Any) -> Dict[str, Any]:
        """Queues a reconstruction (`POST /reconstructions`): `solver`,
        `lambda`, `max_iter`, `truth` and the API's other fields. `truth` is
        a test pattern's name or an image on the scene grid, top row first
        (an array `[nv, nu]` of grey values or `[nv, nu, 3]` of red, green
        and blue, as `polnlos.pattern` returns and `recovered` gives back)."""
        truth = fields.get("truth")
        if truth is not None and not isinstance(truth, (str, dict)):
            fields["truth"] = {"image": np.asarray(truth, dtype=np.float64).tolist()}
        return self._json("POST", "/reconstructions",
                          {"scene": scene, "captures": [int(c) for c in captures], **fields})

    def get_reconstruction(self, rec_id: int) -> Dict[str, Any]:
        """One reconstruction's record."""
        return self._json("GET", f"/reconstructions/{int(rec_id)}")

    def recovered(self, rec_id: int) -> np.ndarray:
        """The recovered image on the scene grid, top row first (the hidden
        plane's +v edge), columns along +u."""
        return np.load(io.BytesIO(self._bytes(f"/reconstructions/{int(rec_id)}/recovered.npy")))

    def measurement(self, rec_id: int) -> np.ndarray:
        """The measurement vector the reconstruction solved for."""
        return np.load(io.BytesIO(self._bytes(f"/reconstructions/{int(rec_id)}/measurement.npy")))

    def report(self, rec_id: int) -> Dict[str, Any]:
        """report.json: conditioning, λ, solver statistics, model check."""
        return self._json("GET", f"/reconstructions/{int(rec_id)}/report.json")

    # -- plans ---------------------------------------------------------------

    def plan(self, scene: str, **fields: Any) -> Dict[str, Any]:
        """Starts a plan over every block of `scene` (`POST /plans`):
        `exposure_us` (or `exposure`), `frames`, `dark_frames`, `reconstruct`."""
        return self._json("POST", "/plans", {"scene": scene, **fields})

    def get_plan(self, plan_id: int) -> Dict[str, Any]:
        """A plan: its state, current step, captures and reconstruction."""
        return self._json("GET", f"/plans/{int(plan_id)}")

    def continue_plan(self, plan_id: int) -> Dict[str, Any]:
        """Tells a plan waiting for the operator that the step is done."""
        return self._json("POST", f"/plans/{int(plan_id)}/continue")

    def cancel_plan(self, plan_id: int) -> Dict[str, Any]:
        """Cancels a plan; its finished captures are kept."""
        return self._json("DELETE", f"/plans/{int(plan_id)}")

    # -- calibrations ----------------------------------------------------------

    def calibrations(self) -> Dict[str, Any]:
        """The gains reconstructions use and each scene's colour calibration
        (`GET /calibrations`)."""
        return self._json("GET", "/calibrations")

    def calibrate(self, capture_id: int, target: Optional[str] = None) -> Dict[str, Any]:
        """Fits a pose's homography to a done `kind="target"` capture of the
        dot target (`POST /calibrations`): `homography`, `rms_px`,
        `model_check` and the scene file rewritten with it (`scene_toml`).
        `target` is the target as TOML text (default: the shipped 5x5 dots)."""
        body: Dict[str, Any] = {"capture": int(capture_id)}
        if target is not None:
            body["target"] = target
        return self._json("POST", "/calibrations", body)

    def calibrate_colour(self, capture_id: int) -> Dict[str, Any]:
        """Measures a colour camera's balance (a gain per colour) from a done
        light capture of a white or grey field and stores it for the
        capture's scene (`POST /calibrations/colour`); reconstructions of that
        scene are then `calibrated` per colour."""
        return self._json("POST", "/calibrations/colour", {"capture": int(capture_id)})

    def calibrate_wall(self, scene: str, captures: Optional[List[int]] = None,
                       source: Optional[List[float]] = None,
                       sources: Optional[List[Dict[str, Any]]] = None) -> Dict[str, Any]:
        """Fits the wall (alpha, ior, kd) and the radiometric gain to
        `kind="source"` captures (`POST /calibrations/wall`): one source
        position (`source` [u, v] metres and its `captures`, one per block)
        or several (`sources`: a list of {"source": [u, v], "captures": [...]})."""
        body: Dict[str, Any] = {"scene": scene}
        if captures is not None:
            body["captures"] = [int(c) for c in captures]
        if source is not None:
            body["source"] = [float(x) for x in source]
        if sources is not None:
            body["sources"] = sources
        return self._json("POST", "/calibrations/wall", body)

    def calibrate_scene(self, scene: str, captures: List[int], free: Optional[List[str]] = None,
                        known: Any = None, range_m: Optional[float] = None,
                        max_evaluations: Optional[int] = None, wait: bool = True,
                        timeout: float = 3600.0) -> Dict[str, Any]:
        """Fits the scene's geometry to its captures (`POST /calibrations/scene`)
        as a job: the occluders' translation, the hidden plane's offset and
        the distance by default (`free` chooses: occluder-x/y/z, scene-u/v,
        distance, occluder-yaw, wall-u/v). `known` is the image the hidden
        monitor showed (a pattern name or an array, top row first) for a
        calibration shot. Once done, every later reconstruction of the scene
        uses the fitted geometry (its report's `geometry` names it). With
        `wait`, returns the calibration when it ends (`fit["fitted"]`: each
        offset and uncertainty; `placed_toml`); else the accepted job."""
        body: Dict[str, Any] = {"scene": scene, "captures": [int(c) for c in captures]}
        if free is not None:
            body["free"] = list(free)
        if known is not None:
            body["known"] = known if isinstance(known, (str, dict)) else {
                "image": np.asarray(known, dtype=np.float64).tolist()}
        if range_m is not None:
            body["range_m"] = float(range_m)
        if max_evaluations is not None:
            body["max_evaluations"] = int(max_evaluations)
        accepted = self._json("POST", "/calibrations/scene", body)
        if not wait:
            return accepted
        self.wait(accepted, timeout=timeout)
        return self.scene_calibration(accepted["id"])

    def scene_calibration(self, calibration_id: int) -> Dict[str, Any]:
        """One scene calibration (`GET /calibrations/scene/{id}`)."""
        return self._json("GET", f"/calibrations/scene/{int(calibration_id)}")

    def scene_calibrations(self) -> List[Dict[str, Any]]:
        """Every scene calibration, newest first (`GET /calibrations/scene`)."""
        return self._json("GET", "/calibrations/scene")

    def delete_scene_calibration(self, calibration_id: int) -> None:
        """Deletes a scene calibration: its scene serves the newest done one
        left, or its file's geometry (`DELETE /calibrations/scene/{id}`)."""
        with self._request("DELETE", f"/calibrations/scene/{int(calibration_id)}"):
            pass

    # -- live view -----------------------------------------------------------

    def live_start(self, scene: str, pose: str, record: Optional[int] = None,
                   radiometry: Optional[str] = None, **fields: Any) -> Dict[str, Any]:
        """Starts the live view (`POST /live`): the capture request repeated,
        `frames` the rolling window (1 to 64), `progressive` its solver
        settings (`truth`, `lambda`, `captures`), `difference` (e.g.
        `{"background_s": 10}`) to see what moves and track it. `record=N`
        stores the session's first N frames (after its dark frames) as a new
        capture, to reconstruct again later: `live()["recording"]` names it
        (`capture`, `frames` written, `of`, `state`); a session that ends
        first keeps the frames it got. `radiometry="fitted"` fits each
        window's gain and background per colour, as a reconstruction of a
        photo does (`live()["last"]["fitted"]`), `"calibrated"` divides by
        the scene's gain; absent, it is chosen as a reconstruction's is
        (`live()["radiometry"]` says which and why). Returns its state."""
        body: Dict[str, Any] = {"scene": scene, "pose": pose, **fields}
        if record is not None:
            body["record"] = {"frames": record}
        if radiometry is not None:
            body["progressive"] = {**body.get("progressive", {}), "radiometry": radiometry}
        return self._json("POST", "/live", body)

    def live(self) -> Dict[str, Any]:
        """The live view's state (`GET /live`): results, results_per_second,
        median_latency_ms, the newest result (`last`) and the recording
        (`recording`), if one was asked for."""
        return self._json("GET", "/live")

    def live_image(self) -> bytes:
        """The newest live image, a 16-bit PNG on the scene grid."""
        return self._bytes("/live/image.png")

    def live_track(self) -> List[Dict[str, Optional[float]]]:
        """The difference mode's track (`GET /live/track.csv`), one dict per
        result: `time_s` (Unix seconds), `u_m`, `v_m` (the moving object's
        centroid on the hidden-scene plane, metres) and `sigma_u_m`,
        `sigma_v_m` (its standard deviations); the centroid's are None when
        nothing moved."""
        lines = self._bytes("/live/track.csv").decode().splitlines()
        if not lines:
            return []
        names = lines[0].split(",")
        return [
            {n: (float(v) if v else None) for n, v in zip(names, line.split(","))}
            for line in lines[1:]
            if line
        ]

    def live_stop(self) -> Dict[str, Any]:
        """Stops the live view; its last state, as `off`."""
        return self._json("DELETE", "/live")

    # -- waiting and events --------------------------------------------------

    def job(self, job: str) -> Dict[str, Any]:
        """A capture or reconstruction by job id (`capture-3`)."""
        return self._json("GET", f"/jobs/{job}")

    def wait(self, accepted: Dict[str, Any], timeout: float = 600.0,
             poll: float = 0.1) -> Dict[str, Any]:
        """Polls a job (an accepted capture or reconstruction) or a plan until
        it ends (or, for a plan, waits for the operator); returns its record.
        Raises PolnlosError when it failed or time ran out."""
        if "job" in accepted:
            fetch = lambda: self.job(accepted["job"])  # noqa: E731
        elif "id" in accepted:
            fetch = lambda: self.get_plan(accepted["id"])  # noqa: E731
        else:
            raise ValueError("give the answer of capture(), reconstruct() or plan()")
        end = time.monotonic() + timeout
        while True:
            record = fetch()
            state = record.get("state")
            if state in _FINAL or state == "waiting_for_operator":
                if state == "failed":
                    raise PolnlosError(f"{accepted.get('job', 'plan')} failed: {record.get('error')}")
                return record
            if time.monotonic() > end:
                raise PolnlosError(f"{accepted.get('job', 'plan')} still {state} after {timeout} s")
            time.sleep(poll)

    def events(self, timeout: Optional[float] = None) -> Iterator[Dict[str, Any]]:
        """The daemon's event stream (`GET /events`, server-sent events), one
        dict per event, as long as the connection lasts; `timeout` bounds the
        wait for each line (the daemon sends a keep-alive every 15 s)."""
        r = self._request("GET", "/events", timeout=timeout or self.timeout)
        with r:
            data: List[str] = []
            for raw in r:
                line = raw.decode("utf-8").rstrip("\r\n")
                if line.startswith("data:"):
                    data.append(line[5:].lstrip(" "))
                elif line == "" and data:
                    yield json.loads("\n".join(data))
                    data = []
