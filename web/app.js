// polnlos web page: the daemon's own HTTP API, nothing else (no CDN, no
// framework). Reads are polled every second and refreshed on server-sent
// events; images are fetched with the token and shown as object URLs.
"use strict";

const $ = (sel) => document.querySelector(sel);
const tokenInput = $("#token");
tokenInput.value = localStorage.getItem("polnlos-token") || "";
tokenInput.addEventListener("change", () => {
  localStorage.setItem("polnlos-token", tokenInput.value.trim());
  refresh();
});

function headers(json) {
  const h = {};
  const t = tokenInput.value.trim();
  if (t) h["Authorization"] = "Bearer " + t;
  if (json) h["Content-Type"] = "application/json";
  return h;
}

async function api(method, path, body) {
  const r = await fetch(path, {
    method,
    headers: headers(body !== undefined),
    body: body === undefined ? undefined : JSON.stringify(body),
  });
  let json = null;
  try { json = await r.json(); } catch (_) { /* not JSON */ }
  return { status: r.status, json, headers: r.headers };
}

// Says which rows of a list the catalogue could not read (the daemon names
// them in a header and leaves them out of the list), or nothing.
function unreadable(r, kind, target) {
  const ids = r.headers.get("polnlos-unreadable");
  text(target, ids
    ? `${kind} ${ids.split(",").join(", ")} could not be read from the catalogue and ${ids.includes(",") ? "are" : "is"} left out of this list; the daemon's log says why.`
    : "");
}

// Shows `path` in `img` (with the token); false when there is no image (yet).
const shown = new Map();
async function showImage(img, path) {
  const r = await fetch(path, { headers: headers(false), cache: "no-store" });
  if (!r.ok) return false;
  const url = URL.createObjectURL(await r.blob());
  const old = shown.get(img);
  img.src = url;
  shown.set(img, url);
  if (old) URL.revokeObjectURL(old);
  return true;
}

function text(el, value) { el.textContent = value; return el; }
function el(tag, attrs, ...children) {
  const e = document.createElement(tag);
  Object.entries(attrs || {}).forEach(([k, v]) => e.setAttribute(k, v));
  children.forEach((c) => e.append(c));
  return e;
}
const block = (c) => c.polarizer_deg === null ? `${c.pose} (no polarizer)` : `${c.pose} at ${c.polarizer_deg}°`;
const active = (s) => s === "queued" || s === "running";
// "2, 3" or "2 3" → [2, 3].
const ids = (v) => String(v).split(/[ ,]+/).filter((s) => s).map(Number);

async function refreshCamera() {
  const h = await api("GET", "/health");
  text($("#health"), h.status === 200 ? (h.json.camera_connected ? "camera connected" : "camera not connected") : "daemon unreachable");
  const c = await api("GET", "/camera");
  if (c.status !== 200) { text($("#camera-status"), (c.json && c.json.detail) || `HTTP ${c.status}`); return; }
  const cam = c.json;
  text($("#camera-status"), cam.connected ? `connected: ${cam.info.id}` + (cam.busy ? ` (busy: ${cam.busy})` : "") : `not connected: ${cam.last_error || ""}`);
  const s = (cam.info && cam.info.settings) || {};
  const k = cam.counters || {};
  const rows = [
    ["exposure", s.exposure_us !== undefined ? `${s.exposure_us} µs` : "-"],
    ["gain", s.gain], ["pixel format", s.pixel_format], ["region", JSON.stringify(s.region)],
    ["frames received", k.completed], ["broken frames", k.failed],
    ["dropped frames", k.underruns], ["timeouts", k.timeouts], ["reconnects", k.connects],
  ];
  const table = $("#camera-facts");
  table.replaceChildren(...rows.map(([a, b]) => el("tr", {}, el("th", {}, a), el("td", {}, String(b ?? "-")))));
  if (await showImage($("#live"), "/camera/frame.png")) text($("#live-caption"), "latest frame");
}

async function refreshCaptures() {
  const r = await api("GET", "/captures?limit=20");
  if (r.status !== 200) return;
  unreadable(r, "capture", $("#captures-unreadable"));
  const body = $("#captures tbody");
  const rows = [];
  for (const c of r.json) {
    const total = c.frames + c.dark_frames;
    const bar = el("progress", { class: "progress", max: String(total), value: String(c.frames_taken) });
    const frames = el("td", {}, bar, ` ${c.frames_taken}/${total}`);
    const prog = el("td", {});
    const img = el("img", { width: "64", height: "64", alt: "", class: "progressive" });
    prog.append(img);
    showImage(img, `/captures/${c.id}/progressive.png`).then((ok) => { if (!ok) img.remove(); });
    const actions = el("td", {});
    if (active(c.state)) {
      const b = el("button", { class: "cancel", "data-job": `capture-${c.id}` }, "Cancel");
      b.addEventListener("click", () => cancel(`capture-${c.id}`));
      actions.append(b);
    }
    rows.push(el("tr", { id: `capture-${c.id}` },
      el("td", {}, String(c.id)),
      el("td", {}, `${c.scene}, ${block(c)}${c.kind === "dark" ? " (dark)" : ""}`),
      el("td", { class: `state state-${c.state}` }, c.state + (c.error ? `: ${c.error}` : "")),
      frames, prog, actions));
  }
  body.replaceChildren(...rows);
}

function reportText(r) {
  const rep = r.report || {};
  const lines = [`${r.solver}, captures ${r.captures.join(", ")}`];
  if (r.kappa !== null && r.kappa !== undefined) lines.push(`kappa ${Number(r.kappa).toExponential(3)}`);
  const l = rep.lambda_choice;
  if (l) lines.push(`lambda ${l.lambda.toExponential(3)} (${l.rule}, noise from ${l.noise})`);
  const m = rep.metrics;
  if (m) lines.push(`PSNR ${m.psnr_db.toFixed(2)} dB, SSIM ${m.ssim.toFixed(3)}`);
  (rep.warnings || []).forEach((w) => lines.push(`warning: ${w}`));
  if (r.error) lines.push(`error: ${r.error}`);
  return lines.join("\n");
}

async function refreshReconstructions() {
  const r = await api("GET", "/reconstructions?limit=10");
  if (r.status !== 200) return;
  unreadable(r, "reconstruction", $("#reconstructions-unreadable"));
  const items = [];
  for (const x of r.json) {
    const img = el("img", { alt: `reconstruction ${x.id}` });
    if (x.state === "done") showImage(img, `/reconstructions/${x.id}/image.png`);
    const info = el("div", {},
      el("div", {}, el("strong", {}, `#${x.id} ${x.scene} `), el("span", { class: `state state-${x.state}` }, x.state)),
      el("pre", { class: "report" }, reportText(x)));
    if (active(x.state)) {
      const b = el("button", { class: "cancel" }, "Cancel");
      b.addEventListener("click", () => cancel(`reconstruction-${x.id}`));
      info.append(b);
    }
    items.push(el("div", { class: "result", id: `reconstruction-${x.id}` }, img, info));
  }
  $("#reconstructions").replaceChildren(...items);
}

async function cancel(job) {
  const r = await api("DELETE", `/jobs/${job}`);
  if (r.status >= 400) alert((r.json && r.json.detail) || `HTTP ${r.status}`);
  refresh();
}

let busy = false;
async function refresh() {
  if (busy) return;
  busy = true;
  try {
    await Promise.all([refreshCamera(), refreshCaptures(), refreshReconstructions()]);
  } catch (e) {
    text($("#health"), `error: ${e}`);
  } finally {
    busy = false;
  }
}

function number(v) { return v === "" ? undefined : Number(v); }

$("#capture-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const f = new FormData(ev.target);
  const body = {
    kind: f.get("kind"), scene: f.get("scene"), pose: f.get("pose"),
    polarizer_deg: f.get("polarizer_deg") === "" ? null : Number(f.get("polarizer_deg")),
    exposure_us: number(f.get("exposure_us")), frames: number(f.get("frames")),
    dark_frames: number(f.get("dark_frames")) || 0,
  };
  if (f.get("progressive") && body.kind === "light") {
    body.progressive = { every: number(f.get("every")) };
    if (f.get("truth")) body.progressive.truth = f.get("truth");
  }
  const r = await api("POST", "/captures", body);
  const msg = $("#capture-message");
  msg.className = r.status === 202 ? "message" : "message error";
  text(msg, r.status === 202 ? `queued ${r.json.job}` : (r.json && r.json.detail) || `HTTP ${r.status}`);
  refresh();
});

$("#reconstruction-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const f = new FormData(ev.target);
  const body = {
    scene: f.get("scene"),
    captures: ids(f.get("captures")),
    solver: f.get("solver"),
  };
  if (f.get("truth")) body.truth = f.get("truth");
  const r = await api("POST", "/reconstructions", body);
  const msg = $("#reconstruction-message");
  msg.className = r.status === 202 ? "message" : "message error";
  text(msg, r.status === 202 ? `queued ${r.json.job}` : (r.json && r.json.detail) || `HTTP ${r.status}`);
  refresh();
});

// Calibration forms: both fits answer synchronously (a few seconds at most).
const fmt = (x, digits) => (x === null || x === undefined) ? "-" : Number(x).toPrecision(digits);
function rowsTable(rows) {
  return el("table", { class: "fit" }, ...rows.map(([a, b]) => el("tr", {}, el("th", {}, a), el("td", {}, String(b)))));
}

// A refused fit shows why and clears the previous result, so that no
// numbers stand beside the error.
function refused(message, result, why) {
  const msg = $(message);
  msg.className = "message error";
  text(msg, why);
  $(result).replaceChildren();
}

async function fit(button, message, result, path, body, show) {
  const msg = $(message);
  msg.className = "message";
  text(msg, "fitting…");
  $(button).disabled = true;
  try {
    const r = await api("POST", path, body);
    if (r.status === 200) { text(msg, "fitted"); show(r.json); }
    else refused(message, result, (r.json && r.json.detail) || `HTTP ${r.status}`);
  } finally {
    $(button).disabled = false;
  }
}

function showPose(c) {
  const h = c.homography.map((row) => row.map((x) => fmt(x, 6)).join("  ")).join("\n");
  const file = new Blob([c.scene_toml], { type: "application/toml" });
  const link = el("a", { href: URL.createObjectURL(file), download: `${c.scene}-pose-${c.pose}.toml`, id: "pose-download" }, "download the scene file");
  $("#pose-result").replaceChildren(
    rowsTable([
      ["capture", c.capture], ["scene / pose", `${c.scene} / ${c.pose}`], ["dots", c.dots],
      ["reprojection RMS", `${fmt(c.rms_px, 3)} px`], ["largest", `${fmt(c.max_px, 3)} px`],
      ["region", c.region.join(", ")],
    ]),
    el("div", { class: "fit" }, el("div", {}, "homography (wall m → pixels):"), el("pre", {}, h),
      el("details", {}, el("summary", {}, "scene file to review"), el("pre", { id: "pose-toml" }, c.scene_toml)),
      link));
}

function showWall(w) {
  const p = w.fit.params, s = w.fit.sigma;
  const pm = (k, d) => `${fmt(p[k], d)} ± ${fmt(s[k], 2)}`;
  const rows = [
    ["scene", w.scene], ["captures", w.captures.join(", ")],
    ["GGX roughness α", pm("alpha", 4)], ["refractive index", pm("ior", 4)],
    ["diffuse weight kd", pm("kd", 3)], ["gain", pm("gain", 4)],
  ];
  if (w.configured_gain) rows.push(["configured gain", `${fmt(w.configured_gain, 4)} (fit/configured ${fmt(p.gain / w.configured_gain, 4)})`]);
  rows.push(["residual", `${(100 * w.fit.relative_residual).toFixed(1)} % of the measurement`], ["iterations", w.fit.iterations]);
  if (w.positions.length > 1) {
    w.positions.forEach((p) => rows.push([`source at [${p.source.join(", ")}]`, `captures ${p.captures.join(", ")}, residual ${(100 * p.relative_residual).toFixed(1)} %`]));
  }
  (w.warnings || []).forEach((m) => rows.push(["warning", m]));
  $("#wall-result").replaceChildren(rowsTable(rows));
}

$("#pose-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const f = new FormData(ev.target);
  const body = { capture: Number(f.get("capture")) };
  const target = String(f.get("target") || "").trim();
  if (target) body.target = target;
  await fit("#fit-pose", "#pose-message", "#pose-result", "/calibrations", body, showPose);
});

// Another source position: a copy of the first row, emptied, with a remove button.
$("#add-position").addEventListener("click", () => {
  const row = document.querySelector("#positions .position").cloneNode(true);
  row.querySelectorAll("input").forEach((i) => { i.value = ""; });
  const remove = el("button", { type: "button", class: "remove" }, "remove");
  remove.addEventListener("click", () => row.remove());
  row.append(remove);
  $("#positions").append(row);
});

$("#wall-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const f = new FormData(ev.target);
  const positions = [...document.querySelectorAll("#positions .position")].map((row) => {
    const v = (name) => row.querySelector(`[name=${name}]`).value.trim();
    const n = (name) => v(name) === "" ? NaN : Number(v(name));
    return { source: [n("u"), n("v")], captures: ids(v("captures")) };
  });
  const bad = positions.findIndex((p) => p.source.some((x) => !Number.isFinite(x)) || p.captures.length === 0 || p.captures.some((x) => !Number.isInteger(x)));
  if (bad >= 0) {
    refused("#wall-message", "#wall-result", `position ${bad + 1}: give its capture ids and u, v in metres`);
    return;
  }
  const body = positions.length === 1
    ? { scene: f.get("scene"), ...positions[0] }
    : { scene: f.get("scene"), sources: positions };
  await fit("#fit-wall", "#wall-message", "#wall-result", "/calibrations/wall", body, showWall);
});

async function loadScenes() {
  const r = await api("GET", "/scenes");
  if (r.status !== 200) return;
  document.querySelectorAll("select.scenes").forEach((s) => {
    s.replaceChildren(...r.json.map((n) => el("option", { value: n }, n)));
    s.value = r.json.includes("brewster-crossed") ? "brewster-crossed" : r.json[0];
  });
}

// Server-sent events over fetch (EventSource cannot send the token).
async function events() {
  for (;;) {
    try {
      const r = await fetch("/events", { headers: headers(false) });
      const reader = r.body.getReader();
      const decoder = new TextDecoder();
      let buf = "";
      for (;;) {
        const { value, done } = await reader.read();
        if (done) break;
        buf += decoder.decode(value, { stream: true });
        let cut;
        while ((cut = buf.indexOf("\n\n")) >= 0) {
          const chunk = buf.slice(0, cut);
          buf = buf.slice(cut + 2);
          if (chunk.split("\n").some((l) => l.startsWith("data:"))) refresh();
        }
      }
    } catch (_) { /* reconnect below */ }
    await new Promise((res) => setTimeout(res, 2000));
  }
}

loadScenes();
refresh();
setInterval(refresh, 1000);
events();
