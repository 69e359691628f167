// polnlos web page: the daemon's own HTTP API, nothing else (no CDN, no
// framework). The lists are loaded once and then changed row by row from the
// server-sent events (a job's state, a frame, a progressive step, a
// deletion); a slow resync every 15 s catches what no event says (a row
// edited behind the daemon's back). The live view asks for one frame a second
// while it is on and the tab is visible. Images and downloads are fetched
// with the token and handed over as object URLs.
"use strict";

const $ = (sel) => document.querySelector(sel);
const tokenInput = $("#token");
tokenInput.value = localStorage.getItem("polnlos-token") || "";
tokenInput.addEventListener("change", () => {
  localStorage.setItem("polnlos-token", tokenInput.value.trim());
  loadScenes();
  resync();
  refreshLive();
});

// What the daemon said of the token on the last refused request: "missing",
// "wrong", or null (accepted, or not needed). Shown beside the token field,
// so that a refused read never reads as a camera or daemon problem.
let tokenState = null;
function noteToken(r) {
  if (r.status === 401) {
    const code = r.json && r.json.error;
    tokenState = code === "token_wrong" ? "wrong" : "missing";
  } else if (r.status < 400) {
    tokenState = null;
  }
  const m = $("#token-message");
  m.className = tokenState ? "token-message error" : "token-message";
  text(m, tokenState === "wrong" ? "this token is wrong: the daemon refuses it"
    : tokenState === "missing" ? "this daemon needs its API token: enter it here" : "");
}
// Why a panel shows nothing, when the token is the reason.
function tokenReason() {
  return tokenState === "wrong" ? "the API token entered is wrong"
    : tokenState === "missing" ? "enter the API token (top right) to see this" : null;
}

function headers(json) {
  const h = {};
  const t = tokenInput.value.trim();
  if (t) h["Authorization"] = "Bearer " + t;
  if (json) h["Content-Type"] = "application/json";
  return h;
}

// What the page says when the daemon does not answer at all (stopped,
// restarting, or the network): not the browser's "TypeError: Failed to fetch".
function unreachable() {
  return `the daemon at ${location.host} does not answer: is it running? (systemctl status polnlos); the page retries every 15 s`;
}

async function api(method, path, body) {
  let r;
  try {
    r = await fetch(path, {
      method,
      headers: headers(body !== undefined),
      body: body === undefined ? undefined : JSON.stringify(body),
    });
  } catch (_) {
    // No answer: status 0 with the reason as the detail every caller shows.
    return { status: 0, json: { detail: unreachable() }, headers: new Headers() };
  }
  let json = null;
  try { json = await r.json(); } catch (_) { /* not JSON */ }
  const out = { status: r.status, json, headers: r.headers };
  if (path !== "/health") noteToken(out);
  return out;
}

// Says which rows of a list the catalogue could not read (the daemon names
// them in a header and leaves them out of the list), or nothing.
function unreadable(r, kind, target) {
  const ids = r.headers.get("polnlos-unreadable");
  text(target, ids
    ? `${kind} ${ids.split(",").join(", ")} could not be read from the catalogue and ${ids.includes(",") ? "are" : "is"} left out of this list; the daemon's log says why.`
    : "");
}

// Shows `path` in `img` (with the token); the response (its status says
// why when there is no image).
const shown = new Map();
async function showImage(img, path) {
  const r = await fetch(path, { headers: headers(false), cache: "no-store" });
  if (r.status === 401) {
    let json = null;
    try { json = await r.json(); } catch (_) { /* not JSON */ }
    noteToken({ status: 401, json });
  }
  if (!r.ok) return r;
  const url = URL.createObjectURL(await r.blob());
  const old = shown.get(img);
  img.src = url;
  shown.set(img, url);
  if (old) URL.revokeObjectURL(old);
  return r;
}

// Saves `path` as a file named `name` (with the token); the outcome is kept
// in window.lastDownload for whoever wants to check it.
async function download(path, name) {
  const r = await fetch(path, { headers: headers(false), cache: "no-store" });
  if (!r.ok) {
    let why = `HTTP ${r.status}`;
    try { why = (await r.json()).detail || why; } catch (_) { /* not JSON */ }
    window.lastDownload = { path, status: r.status, bytes: 0 };
    alertIn($("#captures-message"), `${name}: ${why}`);
    return;
  }
  const blob = await r.blob();
  window.lastDownload = { path, status: r.status, bytes: blob.size };
  const url = URL.createObjectURL(blob);
  const a = el("a", { href: url, download: name });
  document.body.append(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10000);
}

function text(el, value) { el.textContent = value; return el; }
function el(tag, attrs, ...children) {
  const e = document.createElement(tag);
  Object.entries(attrs || {}).forEach(([k, v]) => e.setAttribute(k, v));
  children.forEach((c) => e.append(c));
  return e;
}
// A status line says when it was written, and one about a job follows the
// job ("queued capture-3 … · now done"): none keeps saying what is no longer
// true (issue 38: stale status lines).
const clock = () => new Date().toLocaleTimeString();
function say(target, cls, message, job) {
  target.className = cls;
  target.dataset.job = job || "";
  target.dataset.said = message;
  text(target, `${message} (${clock()})`);
}
function alertIn(target, message) { say(target, "message error", message); }
function noteIn(target, message, job) { say(target, "message", message, job); }
// The status lines that follow `job` take its new state (and why it failed).
function follow(job, state, why) {
  for (const m of document.querySelectorAll(".message")) {
    if (!job || m.dataset.job !== job) continue;
    m.className = state === "failed" || state === "interrupted" ? "message error" : "message";
    text(m, `${m.dataset.said} · now ${state.replaceAll("_", " ")}${why ? `: ${why}` : ""} (${clock()})`);
  }
}
const block = (c) => {
  if (c.channels.length > 1) return `${c.pose} (polarizer mosaic, ${c.channels.length} blocks)`;
  const ch = c.channels[0];
  return ch.analyzer === "none" ? `${c.pose} (no polarizer)` : ch.analyzer === "sheet" ? `${c.pose} at ${ch.deg}°${measured(c)}` : `${c.pose} mosaic ${ch.deg}°`;
};
const active = (s) => s === "queued" || s === "running";
// The angle the mount read back, beside the angle asked for, when it differs in print.
const measured = (c) => (c.polarizer_measured_deg === null || c.polarizer_measured_deg === undefined)
  ? "" : ` (measured ${c.polarizer_measured_deg.toFixed(2)}°)`;
// "2, 3" or "2 3" → [2, 3].
const ids = (v) => String(v).split(/[ ,]+/).filter((s) => s).map(Number);

// A button that acts on the second click within 4 s ("Delete" → "Really delete?").
function twoStep(label, confirm, action) {
  const b = el("button", { type: "button", class: "delete" }, label);
  let armed = null;
  b.addEventListener("click", () => {
    if (armed) { clearTimeout(armed); armed = null; text(b, label); action(); return; }
    text(b, confirm);
    armed = setTimeout(() => { armed = null; text(b, label); }, 4000);
  });
  return b;
}

function downloads(items) {
  return el("span", { class: "downloads" }, ...items.map(([label, path, name]) => {
    const b = el("button", { type: "button", class: "download", "data-path": path }, label);
    b.addEventListener("click", () => download(path, name));
    return b;
  }));
}

// ---- camera and live view ----

// The camera's frame (GET /camera): its region [x, y, width, height] and
// binning, which place the live frame's pixels on the sensor.
let liveFrame = null;
// The pose the stage last reached (GET /stage), when the bench has a stage.
let stagePose = null;

async function refreshCamera() {
  const h = await api("GET", "/health");
  text($("#health"), h.status === 200 ? (h.json.camera_connected ? "camera connected" : "camera not connected") : h.status === 0 ? unreachable() : `health: HTTP ${h.status}`);
  const c = await api("GET", "/camera");
  if (c.status !== 200) {
    text($("#camera-status"), (c.status === 401 && tokenReason()) || (c.json && c.json.detail) || `HTTP ${c.status}`);
    $("#camera-facts").replaceChildren();
    return;
  }
  const cam = c.json;
  if (cam.demo) truthFromDemo(cam.demo);
  text($("#camera-status"), cam.connected ? `connected: ${cam.info.id}` + (cam.busy ? ` (busy: ${cam.busy})` : "") : `not connected: ${cam.last_error || ""}`);
  const s = (cam.info && cam.info.settings) || {};
  const k = cam.counters || {};
  // Every setting the camera reads back, by its API name (a new setting shows without a change here).
  const mosaic = cam.info && cam.info.mosaic;
  const bayer = cam.info && cam.info.bayer;
  liveFrame = Array.isArray(s.region) ? { region: s.region, binning: s.binning || [1, 1] } : null;
  $("#view-box").hidden = !mosaic && !bayer;
  // Each sensor's own views: the Stokes images of a mosaic, the colours of a Bayer filter.
  for (const o of $("#view").options) {
    o.hidden = o.value !== "raw" && (o.value === "colour" ? !bayer : !mosaic);
  }
  if ($("#view").selectedOptions[0] && $("#view").selectedOptions[0].hidden) $("#view").value = "raw";
  const rows = [
    ["sensor", mosaic ? `polarizer mosaic (${mosaic}): 0/45/90/135° in one frame` : bayer ? `colour, Bayer ${bayer} (raw; results in colour)` : "monochrome"],
    ...Object.entries(s).map(([name, v]) => [name.replaceAll("_", " "), Array.isArray(v) ? JSON.stringify(v) : v]),
    ["since the daemon started:", ""],
    ["frames received", k.completed], ["broken frames", k.failed],
    ["packets with no free buffer", k.underruns], ["timeouts", k.timeouts], ["connections", k.connects],
  ];
  $("#camera-facts").replaceChildren(...rows.map(([a, b]) => el("tr", {}, el("th", {}, a), el("td", {}, String(b ?? "-")))));
}

// On the demo bench every Truth field starts at the pattern its camera
// shows (once, and only where still "none"). Why: the demo's truth is
// known, and a result with none has no PSNR to judge it by.
let truthDefaulted = false;
function truthFromDemo(demo) {
  if (truthDefaulted) return;
  truthDefaulted = true;
  for (const s of document.querySelectorAll("select[name=truth]")) {
    if (s.value === "" && [...s.options].some((o) => o.value === demo.pattern)) s.value = demo.pattern;
    s.title = `the demo bench shows ${demo.pattern} (scene ${demo.scene})`;
  }
}

function drawHistogram(levels) {
  const cv = $("#histogram");
  const g = cv.getContext("2d");
  g.clearRect(0, 0, cv.width, cv.height);
  const h = levels.histogram;
  const top = Math.log10(Math.max(...h, 1) + 1);
  const w = cv.width / h.length;
  h.forEach((n, k) => {
    const y = n > 0 ? Math.log10(n + 1) / top * (cv.height - 2) : 0;
    g.fillStyle = k === h.length - 1 && levels.saturated > 0 ? "#b00020" : "#1f4e79";
    g.fillRect(k * w, cv.height - y, Math.max(w - 1, 1), y);
  });
  // The peak level as a line, on the histogram's DN range.
  const lo = levels.histogram_low, hi = levels.histogram_high;
  const at = (levels.peak * levels.full_scale - lo) / Math.max(hi - lo, 1);
  g.fillStyle = "#e08000";
  g.fillRect(Math.min(Math.max(at, 0) * cv.width, cv.width - 1), 0, 1, cv.height);
  cv.title = `histogram over ${lo}–${hi} DN of ${levels.full_scale} (log counts)`;
}

// The live view's levels in the units of what it shows: DN and saturation
// for the frame itself; DoLP in % and AoLP in degrees for the Stokes views,
// whose 16 bits encode 0..1 and -90..90 degrees, where "saturated" and "DN"
// mean nothing (issue 38); their saturation is the raw view's.
function levelsText(levels, view) {
  const full = levels.full_scale;
  if (view === "dolp" || view === "aolp") {
    const v = view === "dolp" ? (x) => `${(100 * x / full).toFixed(1)} %` : (x) => `${(180 * x / full - 90).toFixed(1)}°`;
    return `${view === "dolp" ? "DoLP" : "AoLP"} peak ${v(levels.peak * full)} · stretch ${v(levels.low)}–${v(levels.high)} · histogram ${v(levels.histogram_low)}–${v(levels.histogram_high)}, log counts · saturation: see the raw view`;
  }
  const sat = levels.saturated > 0 ? ` · ${(100 * levels.saturated).toFixed(2)} % saturated` : " · none saturated";
  return `peak ${(100 * levels.peak).toFixed(1)} % of full scale${sat} · stretch ${levels.low}–${levels.high} DN of ${full} · histogram ${levels.histogram_low}–${levels.histogram_high} DN, log counts`;
}

let liveBusy = false;
async function refreshLive() {
  if (liveBusy) return;
  liveBusy = true;
  try {
    const stretch = $("#stretch").checked;
    const view = $("#view-box").hidden ? "raw" : $("#view").value;
    const r = await showImage($("#live"), `/camera/frame.png?live=true&stretch=${stretch}&view=${view}`);
    // Frame pixels per image pixel: every view but the raw one is at half resolution.
    if (r.ok) $("#live").dataset.per = view === "raw" ? "1" : "2";
    if (!r.ok) {
      text($("#live-caption"), (r.status === 401 && tokenReason())
        || (r.status === 404 ? "no frame yet: the camera has sent none since the daemon started" : `no frame: HTTP ${r.status}`));
      return;
    }
    const levels = JSON.parse(r.headers.get("polnlos-levels") || "null");
    text($("#live-caption"), `frame at ${new Date().toLocaleTimeString()}` + (stretch ? " (auto-contrast)" : " (full scale)"));
    if (levels) {
      drawHistogram(levels);
      const lv = $("#levels");
      lv.className = view === "raw" && levels.saturated > 0 ? "warning" : "";
      text(lv, levelsText(levels, view));
    }
  } finally {
    liveBusy = false;
  }
}

// Where the wall is in the live frame: the capture form's scene and pose
// (the stage's pose when it has one) through the pose's homography, from
// GET /scenes/{name}/wall; null when unknown (no homography, no camera).
async function wallAim() {
  const form = new FormData($("#capture-form"));
  const scene = form.get("scene");
  if (!scene) return null;
  const r = await api("GET", `/scenes/${encodeURIComponent(scene)}/wall`);
  if (r.status !== 200 || !Array.isArray(r.json)) return null;
  const pose = stagePose || String(form.get("pose") || "").trim();
  const v = r.json.find((w) => w.pose === pose) || r.json[0];
  return v ? { scene, ...v } : null;
}

// A point in unbinned sensor pixels (where a homography maps) in the pixels
// of the frame of `region` and `binning`: the centre of frame pixel X is at
// x0 + b X + (b - 1) / 2 on the sensor (MODEL.md, as the measurement reads it).
// Why: a frame is its region, not the sensor (512 of a 2048 px sensor).
function inFrame(point, region, binning) {
  const b = binning || [1, 1];
  return [0, 1].map((a) => (point[a] - region[a] - (b[a] - 1) / 2) / b[a]);
}

// Zoom in frame pixels: 1x shows one screen pixel per frame pixel (the
// whole 512 px frame, not half of it; a half-resolution view, the colours
// or the Stokes images, at two screen pixels per image pixel, filling the
// same box), and every zoom opens on the wall's image, where a pose's
// homography puts it in the camera's region, else on the frame's centre,
// never on its top-left corner (issues 38, 47, 65).
async function applyZoom() {
  const z = Number($("#zoom").value);
  const img = $("#live");
  // While the next frame loads, its natural width reads 0: the last frame's
  // width holds (a busy daemon's reload used to size the view for 512 px).
  const natural = img.naturalWidth || Number(img.dataset.natural) || 512;
  img.dataset.natural = String(natural);
  // Frame pixels across: the image's, twice a half-resolution view's.
  const across = natural * (Number(img.dataset.per) || 1);
  img.style.width = `${across * z}px`;
  img.style.height = "auto";
  const box = $("#live-box");
  const aim = await wallAim();
  // Screen pixels per frame pixel.
  const scale = img.clientWidth / across;
  if (aim && aim.centre && scale && liveFrame) {
    const [x, y] = inFrame(aim.centre, liveFrame.region, liveFrame.binning);
    box.scrollLeft = Math.max(0, x * scale - box.clientWidth / 2);
    box.scrollTop = Math.max(0, y * scale - box.clientHeight / 2);
    $("#zoom").title = `centred on the wall of ${aim.scene}, pose ${aim.pose} (its homography)`;
  } else {
    box.scrollLeft = Math.max(0, (box.scrollWidth - box.clientWidth) / 2);
    box.scrollTop = Math.max(0, (box.scrollHeight - box.clientHeight) / 2);
    $("#zoom").title = `centred on the frame${aim && aim.why ? `: ${aim.why}` : ""}`;
  }
}
$("#zoom").addEventListener("change", applyZoom);
$("#capture-form").addEventListener("change", (ev) => { if (ev.target.name === "scene" || ev.target.name === "pose") applyZoom(); });
// The first frame, and a frame of another size (a new region or binning),
// sizes the view again.
$("#live").addEventListener("load", () => {
  const img = $("#live");
  if (String(img.naturalWidth) !== img.dataset.natural || img.dataset.per !== img.dataset.sized) {
    img.dataset.sized = img.dataset.per;
    applyZoom();
  }
});
$("#stretch").addEventListener("change", refreshLive);
$("#view").addEventListener("change", refreshLive);
$("#live-on").addEventListener("change", () => { if ($("#live-on").checked) refreshLive(); });

// ---- captures ----

const pageSize = 20;
const paging = { captures: 0, reconstructions: 0 };
const seen = new Map(); // row id -> JSON of the record it shows
const steps = new Map(); // capture id -> progressive steps

const sizes = { captures: pageSize, reconstructions: 10 };
function pager(kind, count) {
  const off = paging[kind];
  text($(`#${kind}-page`), count === 0 && off === 0 ? "none yet" : `${off + 1}–${off + count}`);
  $(`#${kind}-newer`).disabled = off === 0;
  $(`#${kind}-older`).disabled = count < sizes[kind];
}

// The first page keeps its size as new rows come in at the top.
function trim(kind, container) {
  if (paging[kind] > 0) return;
  while (container.children.length > sizes[kind]) {
    seen.delete(container.lastElementChild.id);
    container.lastElementChild.remove();
  }
  pager(kind, container.children.length);
}

function chart(list) {
  // Change from the previous step (log scale) against frames.
  const pts = list.filter((s) => s.change !== null && s.change > 0);
  const svg = document.createElementNS("http://www.w3.org/2000/svg", "svg");
  svg.setAttribute("width", "140"); svg.setAttribute("height", "40"); svg.setAttribute("class", "steps");
  if (pts.length >= 1) {
    const fx = pts.map((s) => s.frames), ly = pts.map((s) => Math.log10(s.change));
    const [x0, x1] = [Math.min(...fx), Math.max(...fx, Math.min(...fx) + 1)];
    const [y0, y1] = [Math.min(...ly), Math.max(...ly, Math.min(...ly) + 1)];
    const d = pts.map((s, k) => `${k ? "L" : "M"}${(4 + 132 * (s.frames - x0) / (x1 - x0)).toFixed(1)},${(4 + 32 * (y1 - Math.log10(s.change)) / (y1 - y0)).toFixed(1)}`).join(" ");
    const path = document.createElementNS("http://www.w3.org/2000/svg", "path");
    path.setAttribute("d", d); path.setAttribute("fill", "none"); path.setAttribute("stroke", "#1f4e79");
    svg.append(path);
  }
  const last = list[list.length - 1];
  const label = last ? `${list.length} steps, change ${last.change === null ? "-" : last.change.toExponential(1)}` + (last.psnr_db !== null && last.psnr_db !== undefined ? `, PSNR ${last.psnr_db.toFixed(2)} dB` : "") : "";
  return el("div", { class: "chart" }, svg, el("div", { class: "step-label" }, label));
}

function progressiveCell(id) {
  const td = el("td", { class: "progressive-cell" });
  const list = steps.get(id);
  if (!list || list.length === 0) return td;
  const img = el("img", { width: "64", height: "64", alt: "", class: "progressive" });
  showImage(img, `/captures/${id}/progressive.png`);
  td.append(img, chart(list));
  return td;
}

// Frames taken per running capture as the frame events say: the record a
// row is redrawn from can be older than the last event.
const taken = new Map();
function captureRow(c) {
  const total = c.frames + c.dark_frames;
  const n = active(c.state) ? Math.max(c.frames_taken, taken.get(c.id) || 0) : c.frames_taken;
  const bar = el("progress", { class: "progress", max: String(total), value: String(n) });
  const frames = el("td", { class: "frames" }, bar, el("span", { class: "count" }, ` ${n}/${total}`));
  // This capture's own losses (frame_counts), when it lost any, in the
  // daemon's words: a lost frame was replaced by a later one, so the count
  // above is of frames received whole.
  const fc = c.frame_counts;
  if (fc && fc.dropped + fc.broken > 0) {
    frames.append(el("div", { class: "lost warning", title: "frames the camera sent that never arrived (dropped) or arrived incomplete (broken); later frames replaced them, and its reconstructions warn" },
      `lost ${fc.dropped + fc.broken} frames (${fc.dropped} dropped, ${fc.broken} broken) besides the ${fc.received} received whole`));
  }
  // Pixels at full scale (clipping): their means are biased low.
  const cl = c.clipping;
  if (cl && cl.saturated > 0) {
    frames.append(el("div", { class: "saturated warning", title: "pixels at the camera's full scale: their values are only lower bounds; lower the exposure" },
      `saturated: ${cl.saturated} px in one frame (${(100 * cl.saturated / Math.max(cl.pixels, 1)).toFixed(2)} %), ${cl.frames_saturated} frames`));
  }
  const files = c.import
    ? [["measurement", `/captures/${c.id}/measurement.npy`, `capture-${c.id}-measurement.npy`]]
    : [["mean", `/captures/${c.id}/mean.tiff`, `capture-${c.id}-mean.tiff`],
      ["frames", `/captures/${c.id}/frame.tiff`, `capture-${c.id}-frames.tiff`]];
  if (c.dark_frames > 0) files.push(["dark", `/captures/${c.id}/dark.tiff`, `capture-${c.id}-dark.tiff`]);
  if (c.frames > 1) files.push(["variance", `/captures/${c.id}/variance.tiff`, `capture-${c.id}-variance.tiff`]);
  if (!c.import) files.push(["preview", `/captures/${c.id}/preview.png`, `capture-${c.id}-preview.png`]);
  const actions = el("td", {});
  if (active(c.state)) {
    const b = el("button", { class: "cancel", "data-job": `capture-${c.id}` }, "Cancel");
    b.addEventListener("click", () => cancel(`capture-${c.id}`));
    actions.append(b);
  } else {
    actions.append(twoStep("Delete", "Really delete?", () => deleteCapture(c.id, false)));
  }
  if (c.state === "done" && c.kind === "light") {
    const g = el("button", { type: "button", class: "fit-geometry", title: "fit the scene's geometry to this capture (Calibration: Geometry)" }, "Fit geometry");
    g.addEventListener("click", () => fitGeometryOf(c));
    actions.append(g);
  }
  const dark = c.dark_capture ? ` − dark ${c.dark_capture}` : "";
  return el("tr", { id: `capture-${c.id}` },
    el("td", {}, String(c.id)),
    el("td", { class: `kind kind-${c.kind}`, title: c.import ? `imported ${c.import.name || ""} (${c.import.format}, ${c.import.bytes} bytes, sha256 ${c.import.sha256})` : "" },
      c.import ? `${c.kind}, imported ${c.import.format}` : c.kind),
    el("td", {}, `${c.scene}, ${block(c)}${dark}`, planMark(planOf.captures.get(c.id))),
    el("td", { class: `state state-${c.state}` }, c.state + (c.error ? `: ${c.error}` : "")),
    frames, progressiveCell(c.id), el("td", {}, c.state === "done" ? downloads(files) : ""), actions);
}

// Puts record `x` of `kind` ("capture" or "reconstruction") into the list
// `container`: replaces its element when the record changed (or `force`),
// inserts it in id order when new and `insert` (a page being loaded, or an
// event while the first page is shown), and leaves it alone otherwise (a
// selection in it survives). True when it was drawn.
function upsert(kind, x, force, container, build, insert) {
  const key = `${kind}-${x.id}`;
  const json = JSON.stringify(x);
  const old = document.getElementById(key);
  if (old && seen.get(key) === json && !force) return false;
  if (!old && !insert) return false;
  seen.set(key, json);
  // Steps are asked for only where the daemon has them; a running
  // capture's arrive as events.
  if (kind === "capture" && x.progressive && !steps.has(x.id)) loadSteps(x.id);
  const node = build(x);
  if (old) old.replaceWith(node);
  else {
    const after = [...container.children].find((r) => Number(r.id.split("-")[1]) < x.id);
    container.insertBefore(node, after || null);
  }
  return true;
}

function upsertCapture(c, force) {
  const body = $("#captures tbody");
  if (upsert("capture", c, force, body, captureRow, paging.captures === 0)) trim("captures", body);
}

async function loadSteps(id) {
  steps.set(id, []);
  const r = await api("GET", `/captures/${id}/progressive.json`);
  if (r.status === 200 && Array.isArray(r.json) && r.json.length) {
    steps.set(id, r.json);
    const c = seen.get(`capture-${id}`);
    if (c) upsertCapture(JSON.parse(c), true);
  }
}

async function loadCaptures() {
  const r = await api("GET", `/captures?limit=${pageSize}&offset=${paging.captures}`);
  if (r.status !== 200) return;
  unreadable(r, "capture", $("#captures-unreadable"));
  const keep = new Set(r.json.map((c) => `capture-${c.id}`));
  [...$("#captures tbody").children].forEach((row) => { if (!keep.has(row.id)) { row.remove(); seen.delete(row.id); } });
  r.json.forEach((c) => upsert("capture", c, false, $("#captures tbody"), captureRow, true));
  pager("captures", r.json.length);
}

async function deleteCapture(id, withReconstructions) {
  const r = await api("DELETE", `/captures/${id}${withReconstructions ? "?with_reconstructions=true" : ""}`);
  const msg = $("#captures-message");
  if (r.status === 200) {
    noteIn(msg, `deleted capture ${id}` + (r.json.reconstructions.length ? ` and reconstruction ${r.json.reconstructions.join(", ")}` : ""));
    removeCapture(id);
    r.json.reconstructions.forEach(removeReconstruction);
    return;
  }
  // The API's way out (a query string) is the button below on the page.
  alertIn(msg, ((r.json && r.json.detail) || `HTTP ${r.status}`).replace(/, or ask for \?with_reconstructions=true$/, ""));
  if (r.status === 409 && !withReconstructions && /reconstructions? [0-9, ]+ uses?/.test(msg.textContent)) {
    const b = twoStep("delete it with them", "Really delete them all?", () => deleteCapture(id, true));
    b.id = "delete-with-reconstructions";
    msg.append(" ", b);
  }
}

function removeCapture(id) {
  const row = document.getElementById(`capture-${id}`);
  if (row) row.remove();
  seen.delete(`capture-${id}`);
}

// ---- reconstructions ----

const compare = new Set();

// The report's radiometry, and a fitted result's per-channel gain and λ.
function radiometryLines(rep) {
  const out = [];
  const rad = rep.radiometry;
  if (rad) out.push(`radiometry ${rad.mode}${rad.given ? "" : " (chosen)"}: ${rad.reason}`);
  (rep.channels || []).forEach((c, k) => out.push(
    `channel ${k}: gain ${c.gain.toExponential(3)}, λ ${c.lambda.toExponential(3)}, misfit ${num(c.misfit / c.misfit_floor, 3)} of its λ = 0 floor${c.informative ? "" : ", no signal"}`));
  return out;
}

// A report's number with `digits` decimals; "inf" (as report.json writes an
// infinite PSNR) and a missing number as they are.
function num(v, digits) {
  return typeof v === "number" ? v.toFixed(digits) : String(v ?? "-");
}

function reportLines(r) {
  const rep = r.report || {};
  const lines = [`${r.solver}, captures ${r.captures.join(", ")}`, ...radiometryLines(rep)];
  if (r.kappa !== null && r.kappa !== undefined) lines.push(`kappa ${Number(r.kappa).toExponential(3)}`);
  const l = rep.lambda_choice;
  if (l) lines.push(`lambda ${l.lambda.toExponential(3)} (${l.rule}, noise from ${l.noise})`);
  else if (r.params && r.params.lambda !== undefined && r.params.lambda !== null) lines.push(`lambda ${Number(r.params.lambda).toExponential(3)} (given)`);
  const mc = rep.model_check;
  if (mc) lines.push(`model check χ²/dof ${num(mc.chi2_per_dof, 2)}` + (mc.explained === false ? " (T does not explain the measurement)" : ""));
  const m = rep.metrics;
  const truth = r.params ? truthName(r.params.truth) : null;
  if (m) lines.push(`PSNR ${num(m.psnr_db, 2)} dB, SSIM ${num(m.ssim, 3)}, ZNCC ${num(m.zncc, 3)}` + (truth ? ` against truth ${truth}` : ""));
  if (r.error) lines.push(`error: ${r.error}`);
  return lines.join("\n");
}

// A hidden-scene image (a result, its truth, a live result) at its grid's
// aspect, a whole number of screen pixels per scene pixel and at least
// RESULT_SIDE px on its short side. Why: an 8x8 result drawn at 8 x 8 px is
// a dot, and a fixed square squashes a 36 x 29 or 10 x 6 grid.
const RESULT_SIDE = 160;
function fitScene(img) {
  const w = img.naturalWidth, h = img.naturalHeight;
  if (!w || !h) return;
  const k = Math.max(1, Math.ceil(RESULT_SIDE / Math.min(w, h)));
  img.style.width = `${w * k}px`;
  img.style.height = `${h * k}px`;
}
// Every scene image, wherever it is drawn, sized as it loads.
document.addEventListener("load", (ev) => {
  if (ev.target instanceof HTMLImageElement && ev.target.classList.contains("scene-image")) fitScene(ev.target);
}, true);
// A reconstruction's truth as people read it: its pattern's name, or
// "image" for an image the request gave; null for none.
function truthName(t) {
  if (t === null || t === undefined) return null;
  return typeof t === "string" ? t : "image";
}

function colorBar() {
  return el("div", { class: "colorbar", title: "recovered radiance, units of T l: every result and truth on this one scale" },
    el("span", {}, "1"), el("div", { class: "bar" }), el("span", {}, "0"));
}

function reconstructionItem(x) {
  const figs = el("div", { class: "figures" });
  const img = el("img", { alt: `reconstruction ${x.id}`, class: "result-image scene-image" });
  figs.append(el("figure", {}, img, el("figcaption", {}, "result")));
  if (x.state === "done") showImage(img, `/reconstructions/${x.id}/image.png`);
  if (x.params && x.params.truth) {
    const name = truthName(x.params.truth);
    const t = el("img", { alt: `truth ${name}`, class: "truth-image scene-image" });
    figs.append(el("figure", {}, t, el("figcaption", {}, `truth: ${name}`)));
    showImage(t, `/reconstructions/${x.id}/truth.png`);
  }
  figs.append(colorBar());
  const warnings = ((x.report || {}).warnings || []).map((w) => el("li", { class: "warning" }, w));
  const info = el("div", { class: "info" },
    el("div", {}, el("strong", {}, `#${x.id} ${x.scene} `), el("span", { class: `state state-${x.state}` }, x.state), planMark(planOf.reconstructions.get(x.id))),
    el("pre", { class: "report" }, reportLines(x)));
  if (warnings.length) info.append(el("ul", { class: "warnings" }, ...warnings));
  const notes = ((x.report || {}).notes || []).map((n) => el("li", { class: "note" }, n));
  if (notes.length) info.append(el("details", { class: "notes" }, el("summary", {}, `${notes.length} note${notes.length > 1 ? "s" : ""} on this bench`), el("ul", {}, ...notes)));
  if (active(x.state)) {
    const b = el("button", { class: "cancel" }, "Cancel");
    b.addEventListener("click", () => cancel(`reconstruction-${x.id}`));
    info.append(b);
  } else {
    if (x.state === "done") {
      const grid = (x.report || {}).scene_grid || {};
      const side = Math.max(grid.nu || 0, grid.nv || 0);
      const scale = side > 0 ? Math.max(1, Math.floor(512 / side)) : 32;
      info.append(downloads([
        ["image.png", `/reconstructions/${x.id}/image.png`, `reconstruction-${x.id}.png`],
        [`image.png ×${scale}`, `/reconstructions/${x.id}/image.png?scale=${scale}`, `reconstruction-${x.id}-x${scale}.png`],
        ["recovered.npy", `/reconstructions/${x.id}/recovered.npy`, `reconstruction-${x.id}-recovered.npy`],
        ["measurement.npy", `/reconstructions/${x.id}/measurement.npy`, `reconstruction-${x.id}-measurement.npy`],
        ["report.json", `/reconstructions/${x.id}/report.json`, `reconstruction-${x.id}-report.json`],
      ]));
      const box = el("input", { type: "checkbox", class: "compare" });
      box.checked = compare.has(x.id);
      box.addEventListener("change", () => { if (box.checked) compare.add(x.id); else compare.delete(x.id); drawCompare(); });
      info.append(el("label", { class: "compare-label" }, box, " compare"));
    }
    info.append(twoStep("Delete", "Really delete?", () => deleteReconstruction(x.id)));
  }
  return el("div", { class: "result", id: `reconstruction-${x.id}` }, figs, info);
}

const records = new Map(); // reconstruction id -> record
function upsertReconstruction(x, force) {
  records.set(x.id, x);
  if (!upsert("reconstruction", x, force, $("#reconstructions"), reconstructionItem, paging.reconstructions === 0)) return;
  trim("reconstructions", $("#reconstructions"));
  if (compare.has(x.id)) drawCompare();
}

async function loadReconstructions() {
  const r = await api("GET", `/reconstructions?limit=10&offset=${paging.reconstructions}`);
  if (r.status !== 200) return;
  unreadable(r, "reconstruction", $("#reconstructions-unreadable"));
  const keep = new Set(r.json.map((x) => `reconstruction-${x.id}`));
  [...$("#reconstructions").children].forEach((item) => { if (!keep.has(item.id)) { item.remove(); seen.delete(item.id); } });
  r.json.forEach((x) => { records.set(x.id, x); upsert("reconstruction", x, false, $("#reconstructions"), reconstructionItem, true); });
  pager("reconstructions", r.json.length);
  drawCompare();
}

async function deleteReconstruction(id) {
  const r = await api("DELETE", `/reconstructions/${id}`);
  const msg = $("#reconstructions-message");
  if (r.status === 200) { noteIn(msg, `deleted reconstruction ${id}`); removeReconstruction(id); }
  else alertIn(msg, (r.json && r.json.detail) || `HTTP ${r.status}`);
}

function removeReconstruction(id) {
  const item = document.getElementById(`reconstruction-${id}`);
  if (item) item.remove();
  seen.delete(`reconstruction-${id}`);
  records.delete(id);
  if (compare.delete(id)) drawCompare();
}

// The ticked reconstructions side by side, one scale, their numbers in one table.
function drawCompare() {
  const chosen = [...compare].sort((a, b) => a - b).map((id) => records.get(id)).filter((x) => x);
  const box = $("#compare");
  if (chosen.length === 0) { box.replaceChildren(); return; }
  const figs = el("div", { class: "figures" });
  chosen.forEach((x) => {
    const img = el("img", { alt: `reconstruction ${x.id}`, class: "compare-image scene-image" });
    showImage(img, `/reconstructions/${x.id}/image.png`);
    figs.append(el("figure", {}, img, el("figcaption", {}, `#${x.id} ${x.scene}`)));
  });
  figs.append(colorBar());
  const num = (x, f) => { try { return f(x); } catch (_) { return "-"; } };
  const rows = [
    ["scene", (x) => x.scene], ["captures", (x) => x.captures.join(", ")], ["solver", (x) => x.solver],
    ["kappa", (x) => Number(x.kappa).toExponential(3)],
    ["lambda", (x) => x.report.lambda_choice ? x.report.lambda_choice.lambda.toExponential(3) : Number(x.params.lambda).toExponential(3)],
    ["PSNR dB", (x) => x.report.metrics.psnr_db.toFixed(2)], ["SSIM", (x) => x.report.metrics.ssim.toFixed(3)],
    ["ZNCC", (x) => x.report.metrics.zncc.toFixed(3)],
  ];
  const table = el("table", { class: "compare-table" },
    el("tr", {}, el("th", {}, ""), ...chosen.map((x) => el("th", {}, `#${x.id}`))),
    ...rows.map(([name, f]) => el("tr", {}, el("th", {}, name), ...chosen.map((x) => el("td", {}, String(num(x, f)))))));
  box.replaceChildren(figs, table);
}

async function cancel(job) {
  const r = await api("DELETE", `/jobs/${job}`);
  if (r.status >= 400) alert((r.json && r.json.detail) || `HTTP ${r.status}`);
}

// ---- events ----

async function onEvent(v) {
  if (String(v.job || "").startsWith("scene-fit-")) {
    geometryEvent(v);
    return;
  }
  const [kind, id] = String(v.job || "").split("-");
  if (v.type === "job") {
    // A capture turns the mount, moves the stage, switches the light: read them back.
    if (v.state !== "running" && kind === "capture") refreshRig();
    const r = await api("GET", `/${kind}s/${id}`);
    if (r.status !== 200) return;
    follow(v.job, r.json.state, r.json.error);
    if (kind === "capture" && !active(r.json.state)) taken.delete(r.json.id);
    if (kind === "capture") upsertCapture(r.json);
    else upsertReconstruction(r.json);
    if (kind === "capture") refreshCamera();
  } else if (v.type === "frame") {
    taken.set(Number(id), Math.max(v.taken, taken.get(Number(id)) || 0));
    const row = document.getElementById(`capture-${id}`);
    if (row) {
      const bar = row.querySelector("progress");
      bar.max = v.total; bar.value = v.taken;
      text(row.querySelector(".count"), ` ${v.taken}/${v.total}`);
    }
  } else if (v.type === "progressive") {
    const n = Number(id);
    const list = steps.get(n) || [];
    list.push(v);
    steps.set(n, list);
    const c = seen.get(`capture-${n}`);
    if (c) upsertCapture(JSON.parse(c), true);
  } else if (v.type === "deleted") {
    if (v.kind === "capture") removeCapture(v.id); else removeReconstruction(v.id);
  } else if (v.type === "camera") {
    refreshCamera();
  } else if (v.type === "plan") {
    showPlan(v.plan);
    loadPlans();
  }
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
          chunk.split("\n").filter((l) => l.startsWith("data:")).forEach((l) => {
            try { onEvent(JSON.parse(l.slice(5))); } catch (_) { /* not an event of ours */ }
          });
        }
      }
    } catch (_) { /* reconnect below */ }
    await new Promise((res) => setTimeout(res, 2000));
    resync();
  }
}

let syncing = false;
async function resync() {
  if (syncing) return;
  syncing = true;
  try {
    await Promise.all([refreshCamera(), refreshRig(), loadCaptures(), loadReconstructions(), loadPlans(true)]);
  } catch (e) {
    text($("#health"), e instanceof TypeError ? unreachable() : `error: ${e}`);
  } finally {
    syncing = false;
  }
}

["captures", "reconstructions"].forEach((kind) => {
  const size = sizes[kind];
  const load = kind === "captures" ? loadCaptures : loadReconstructions;
  $(`#${kind}-newer`).addEventListener("click", () => { paging[kind] = Math.max(0, paging[kind] - size); load(); });
  $(`#${kind}-older`).addEventListener("click", () => { paging[kind] += size; load(); });
});

// ---- forms ----

// A form field that does not hold what it must: named beside the field,
// and nothing is sent.
class FieldError extends Error {}

// Reads numeric field `name` of `form`: undefined when empty (unless
// `required`), its number when it is one ("auto" where `auto`); anything
// else marks the field with why and throws, so unreadable or missing input
// never turns into a default (issue 38: frames "abc" ran a plan of 1 frame,
// exposure "50ms" became 20000 us; issue 65: an empty Frames ran 1 frame,
// an empty Exposure 20000 us).
function numeric(form, name, { integer = false, auto = false, required = false } = {}) {
  const input = form.querySelector(`[name=${name}]`);
  if (!input) return undefined;
  clearFieldError(input);
  const raw = String(input.value).trim();
  const want = `${integer ? "a whole number" : "a number"}${auto ? " or auto" : ""}`;
  if (raw === "" && !required) return undefined;
  if (auto && raw === "auto") return "auto";
  const v = Number(raw);
  if (raw === "" || !Number.isFinite(v) || (integer && !Number.isInteger(v))) {
    const why = raw === "" ? `${name}: empty; give ${want}${typeof required === "string" ? ` (${required})` : ""}`
      : `${name}: "${raw}" is not ${want}`;
    markField(input, why);
    throw new FieldError(why);
  }
  return v;
}

function markField(input, why) {
  input.classList.add("invalid");
  input.setAttribute("aria-invalid", "true");
  input.after(el("span", { class: "field-error" }, why));
}

function clearFieldError(input) {
  input.classList.remove("invalid");
  input.removeAttribute("aria-invalid");
  const next = input.nextElementSibling;
  if (next && next.classList.contains("field-error")) next.remove();
}

// Why Frames may be empty only with an automatic exposure.
const FRAMES_OR_PLAN = "or auto exposure and an empty Frames: the plan's";

// Runs `build` (which reads the form's fields); a FieldError shows in `msg`
// and gives null, so that the caller sends nothing.
// The capture ids of field `name` of `form` (numbers separated by commas
// or spaces); a FieldError naming what is not one, or an empty field.
function captureIds(form, name) {
  const input = form.querySelector(`[name=${name}]`);
  const raw = String(input ? input.value : "").trim();
  if (input) clearFieldError(input);
  const parts = raw.split(/[ ,]+/).filter((p) => p);
  const bad = parts.find((p) => !/^[0-9]+$/.test(p));
  if (parts.length === 0 || bad !== undefined) {
    const why = bad === undefined
      ? `${name}: empty; give capture ids such as 1, 2`
      : `${name}: "${bad}" is not a capture id (a whole number; several separated by commas or spaces)`;
    if (input) markField(input, why);
    throw new FieldError(why);
  }
  return parts.map(Number);
}

function fields(msg, build) {
  try {
    return build();
  } catch (e) {
    if (!(e instanceof FieldError)) throw e;
    alertIn(msg, `not sent: ${e.message}`);
    return null;
  }
}

// The capture form's request body for a capture of `kind` (null, with the
// reason shown, when a field cannot be read or no scene is known).
function captureBody(kind) {
  const f = new FormData($("#capture-form"));
  if (!f.get("scene")) {
    alertIn($("#capture-message"), tokenReason() || "no scene to choose: the daemon has not sent its scene list (see the message at the top)");
    return null;
  }
  const form = $("#capture-form");
  const msg = $("#capture-message");
  return fields(msg, () => {
    const exposure = numeric(form, "exposure_us", { auto: true, required: true });
    const polarizer = numeric(form, "polarizer_deg");
    const b = {
      kind, scene: f.get("scene"), pose: f.get("pose"),
      polarizer_deg: polarizer === undefined ? null : polarizer,
      frames: numeric(form, "frames", { integer: true, required: exposure !== "auto" && FRAMES_OR_PLAN }),
      dark_frames: numeric(form, "dark_frames", { integer: true }) || 0,
    };
    if (exposure === "auto") b.exposure = "auto"; else b.exposure_us = exposure;
    // Camera settings (inputs marked data-setting): sent when filled, else the capture defaults apply.
    for (const input of form.querySelectorAll("[data-setting]")) {
      const v = input.value.trim();
      if (v !== "") b[input.name] = input.dataset.setting === "number" ? numeric(form, input.name) : v;
    }
    const dark = numeric(form, "dark_capture", { integer: true });
    if (kind !== "dark" && dark !== undefined) { b.dark_capture = dark; b.dark_frames = 0; }
    if (kind === "dark") b.dark_frames = 0;
    if (f.get("progressive") && kind === "light") {
      b.progressive = { every: numeric(form, "every", { integer: true }) };
      if (f.get("truth")) b.progressive.truth = f.get("truth");
      if (f.get("radiometry")) b.progressive.radiometry = f.get("radiometry");
    }
    return b;
  });
}

async function submitCapture(kind) {
  const msg = $("#capture-message");
  const body = captureBody(kind);
  if (!body) return;
  const r = await api("POST", "/captures", body);
  if (r.status !== 202) { alertIn(msg, (r.json && r.json.detail) || `HTTP ${r.status}`); return; }
  noteIn(msg, `queued ${r.json.job}` + (r.json.exposure_us ? ` (${r.json.exposure_us} µs, ${r.json.frames} frames)` : ""), r.json.job);
  if (kind === "dark") {
    $("#capture-form [name=dark_capture]").value = String(r.json.id);
    text(msg, `${msg.textContent}; switch the hidden scene back on: later captures subtract dark capture ${r.json.id}`);
  }
  const c = await api("GET", `/captures/${r.json.id}`);
  if (c.status === 200) upsertCapture(c.json);
}

$("#capture-form").addEventListener("submit", (ev) => {
  ev.preventDefault();
  submitCapture(new FormData(ev.target).get("kind"));
});
$("#take-dark").addEventListener("click", () => submitCapture("dark"));

// ---- live view: the capture form's request repeated, each window solved ----
// POST /live takes the capture body (Frames is the window); GET /live is
// polled while it runs, and the newest image shown beside its numbers.
let liveTimer = null;
let liveResults = -1;

function liveText(v) {
  if (v.state === "off") return "live view off";
  if (v.state === "failed") return `live view failed: ${v.error}`;
  if (v.state === "paused") return `live view paused: ${v.paused_by} has the camera`;
  const parts = [`live view ${v.state}: ${v.results} results`];
  if (v.results_per_second) parts.push(`${v.results_per_second.toFixed(1)} a second`);
  if (v.median_latency_ms) parts.push(`median latency ${v.median_latency_ms.toFixed(0)} ms`);
  if (v.last && v.last.psnr_db != null) parts.push(`PSNR ${v.last.psnr_db.toFixed(2)} dB`);
  if (v.last) parts.push(`windows of ${v.last.frames} frames`);
  if (v.radiometry) parts.push(`radiometry ${v.radiometry.mode}${v.radiometry.given ? "" : " (chosen)"}`);
  const fit = v.last && v.last.fitted;
  if (fit) {
    const each = (xs) => xs.map((x) => x.toExponential(3)).join(" / ");
    parts.push(`gain ${each(fit.gain)}, background ${each(fit.background.map((b) => b[0]))} (first block)`);
  }
  const rec = v.recording;
  if (rec) parts.push(`recording capture ${rec.capture}: ${rec.frames} of ${rec.of} frames, ${rec.state}` + (rec.reason ? ` (${rec.reason})` : ""));
  if (v.difference_background_s) {
    const c = v.centroid;
    const mm = (m) => (1e3 * m).toFixed(1);
    parts.push(c ? `moving object at (${mm(c.u_m)}, ${mm(c.v_m)}) ± (${mm(c.sigma_u_m)}, ${mm(c.sigma_v_m)}) mm` : "nothing moving");
  }
  return parts.join(", ");
}

async function pollLive() {
  const r = await api("GET", "/live");
  if (r.status !== 200) return;
  const v = r.json;
  const on = v.state !== "off";
  $("#live-result").hidden = !on && liveResults < 0;
  $("#stop-live").hidden = !on;
  text($("#live-status"), liveText(v));
  $("#live-track").hidden = !v.difference_background_s;
  if (v.results > 0 && v.results !== liveResults) {
    liveResults = v.results;
    await showImage($("#live-image"), "/live/image.png");
  }
  // The camera's counters (frames received) move with the session.
  if (on || liveTimer) refreshCamera();
  if (!on && liveTimer) { clearInterval(liveTimer); liveTimer = null; }
  if (on && !liveTimer) liveTimer = setInterval(pollLive, 500);
}

$("#start-live").addEventListener("click", async () => {
  const msg = $("#capture-message");
  const body = captureBody("light");
  if (!body) return;
  delete body.kind;
  const truth = new FormData($("#capture-form")).get("truth");
  body.progressive = truth ? { truth } : {};
  const radiometry = new FormData($("#capture-form")).get("radiometry");
  if (radiometry) body.progressive.radiometry = radiometry;
  if (new FormData($("#capture-form")).get("difference")) body.difference = {};
  const record = fields(msg, () => numeric($("#capture-form"), "record", { integer: true }) ?? "none");
  if (record === null) return;
  if (record !== "none") body.record = { frames: record };
  const r = await api("POST", "/live", body);
  if (r.status !== 202) { alertIn(msg, (r.json && r.json.detail) || `HTTP ${r.status}`); return; }
  const rec = r.json.recording;
  noteIn(msg, `live view started: windows of ${r.json.window} frames` + (rec ? `, recording ${rec.of} frames as capture ${rec.capture}` : ""));
  liveResults = -1;
  pollLive();
});

$("#stop-live").addEventListener("click", async () => {
  const r = await api("DELETE", "/live");
  if (r.status === 200) noteIn($("#capture-message"), `live view stopped after ${r.json.results} results`);
  pollLive();
});
pollLive();

$("#reconstruction-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const f = new FormData(ev.target);
  const msg = $("#reconstruction-message");
  const body = fields(msg, () => {
    const b = {
      scene: f.get("scene"),
      captures: captureIds(ev.target, "captures"),
      solver: f.get("solver"),
    };
    if (f.get("truth")) b.truth = f.get("truth");
    if (f.get("radiometry")) b.radiometry = f.get("radiometry");
    const lambda = numeric(ev.target, "lambda", { auto: true });
    if (lambda !== undefined && lambda !== "auto") b.lambda = lambda;
    const iters = numeric(ev.target, "max_iter", { integer: true });
    if (iters !== undefined) b.max_iter = iters;
    return b;
  });
  if (!body) return;
  const r = await api("POST", "/reconstructions", body);
  if (r.status !== 202) { alertIn(msg, (r.json && r.json.detail) || `HTTP ${r.status}`); return; }
  noteIn(msg, `queued ${r.json.job}`, r.json.job);
  const x = await api("GET", `/reconstructions/${r.json.id}`);
  if (x.status === 200) upsertReconstruction(x.json);
});

// A measurement or photo taken elsewhere, sent as the body of
// POST /captures/import; the new capture joins the list.
$("#import-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const f = new FormData(ev.target);
  const msg = $("#import-message");
  const file = $("#import-file").files[0];
  if (!file) { alertIn(msg, "choose a file (.npy, TIFF or PNG)"); return; }
  const q = new URLSearchParams({ scene: f.get("scene"), pose: f.get("pose").trim(), name: file.name });
  const deg = String(f.get("polarizer_deg")).trim();
  if (deg !== "") q.set("polarizer_deg", deg);
  if (f.get("bayer")) q.set("bayer", f.get("bayer"));
  let r;
  try {
    r = await fetch(`/captures/import?${q}`, {
      method: "POST",
      headers: { ...headers(false), "Content-Type": "application/octet-stream" },
      body: await file.arrayBuffer(),
    });
  } catch (_) { alertIn(msg, unreachable()); return; }
  let json = null;
  try { json = await r.json(); } catch (_) { /* not JSON */ }
  noteToken({ status: r.status, json, headers: r.headers });
  if (r.status !== 201) { alertIn(msg, (json && json.detail) || `HTTP ${r.status}`); return; }
  noteIn(msg, `imported ${file.name} as capture ${json.id} (${json.import.format}, ${json.import.colours} channel(s))`);
  upsertCapture(json, true);
});

// ---- plans ----

let shownPlan = null;
// Shows plan `id`: its state, its progress across steps, and the
// operator's prompt with Continue while it waits.
async function showPlan(id) {
  const r = await api("GET", `/plans/${id}`);
  if (r.status !== 200) return;
  const p = r.json;
  follow(`plan-${p.id}`, p.state, p.error);
  shownPlan = p.id;
  $("#plan-status").hidden = false;
  text($("#plan-title"), `plan ${p.id} (${p.scene}): ${p.state.replaceAll("_", " ")}`);
  const bar = $("#plan-progress");
  bar.max = Math.max(1, p.steps.length); bar.value = Math.min(p.step, p.steps.length);
  text($("#plan-step"), `step ${Math.min(p.step + 1, p.steps.length)} of ${p.steps.length}` +
    (p.interim && p.interim.length ? `, interim reconstructions ${p.interim.map((r) => r.reconstruction).join(", ")}` : "") +
    (p.reconstruction ? `, reconstruction ${p.reconstruction}` : "") + (p.error ? `: ${p.error}` : ""));
  const waiting = p.state === "waiting_for_operator";
  text($("#plan-prompt"), waiting ? p.prompt : "");
  $("#plan-continue").hidden = !waiting;
  $("#plan-cancel").hidden = ["done", "failed", "cancelled", "interrupted"].includes(p.state);
}

$("#plan-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const f = new FormData(ev.target);
  const form = ev.target;
  const msg = $("#plan-message");
  const body = fields(msg, () => {
    const exposure = numeric(form, "exposure_us", { auto: true, required: true });
    const b = {
      scene: f.get("scene"),
      frames: numeric(form, "frames", { integer: true, required: exposure !== "auto" && FRAMES_OR_PLAN }),
      dark_frames: numeric(form, "dark_frames", { integer: true }) || 0,
    };
    if (exposure === "auto") b.exposure = "auto"; else b.exposure_us = exposure;
    b.reconstruct = {};
    if (f.get("truth")) b.reconstruct.truth = f.get("truth");
    const every = numeric(form, "progressive_every", { integer: true });
    if (every) b.reconstruct.progressive_every = every;
    if (f.get("interim")) b.reconstruct.interim = true;
    return b;
  });
  if (!body) return;
  const r = await api("POST", "/plans", body);
  if (r.status !== 202) { alertIn(msg, tokenReason() || (r.json && r.json.detail) || `HTTP ${r.status}`); return; }
  noteIn(msg, `plan ${r.json.id} queued: ${r.json.steps.length} steps`, `plan-${r.json.id}`);
  showPlan(r.json.id);
  loadPlans();
});
// ---- the rig ----

// The bench's devices as the daemon reads them back: the mount (the
// polarizer's measured angle, its zero and where the zero came from), the
// stage and the light relay, each with its last error (issue 38: none of
// it was on the page).
async function refreshRig() {
  const [m, s, l] = await Promise.all([api("GET", "/mount"), api("GET", "/stage"), api("GET", "/light")]);
  const err = (v) => v.last_error ? `; last error: ${v.last_error}` : "";
  const cell = (row, r, say) => text($(`#${row} .state`), r.status === 200 ? say(r.json) : (r.json && r.json.detail) || `HTTP ${r.status}`);
  cell("rig-mount", m, (v) => v.kind === "none" ? "none: the polarizer is turned by hand, polarizer_deg trusted"
    : `${v.kind}${v.connected ? "" : " (not connected)"}: polarizer at ${v.polarizer_deg === null ? "?" : v.polarizer_deg.toFixed(2)}° measured`
      + ` (mount ${v.position_deg === null ? "?" : v.position_deg.toFixed(2)}°), zero ${v.zero_deg.toFixed(2)}° from ${v.zero_source}${err(v)}`);
  stagePose = s.status === 200 && s.json.kind !== "none" ? s.json.pose || null : null;
  cell("rig-stage", s, (v) => v.kind === "none" ? "none: the operator moves the camera between poses"
    : `${v.kind}: at pose ${v.pose || "?"}${v.position_m ? ` (${v.position_m.map((x) => x.toFixed(3)).join(", ")} m)` : ""}${err(v)}`);
  cell("rig-light", l, (v) => v.kind === "none" ? "none: the hidden scene's light is switched by hand"
    : `${v.kind} relay ${v.relay}: ${v.on === null ? "unknown" : v.on ? "lit" : "dark"}${err(v)}`);
  $("#mount-zero-form").hidden = !(m.status === 200 && m.json.kind !== "none");
}

$("#mount-zero-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const form = ev.target;
  const msg = $("#rig-message");
  const body = fields(msg, () => ({
    scene: new FormData(form).get("scene"),
    pose: String(new FormData(form).get("pose")).trim(),
    exposure_us: numeric(form, "exposure_us", { required: true }),
    frames: numeric(form, "frames", { integer: true, required: true }),
  }));
  if (!body) return;
  noteIn(msg, "sweeping the mount around its zero…");
  const r = await api("POST", "/mount/zero", body);
  if (r.status !== 200) { alertIn(msg, (r.json && r.json.detail) || `HTTP ${r.status}`); return; }
  noteIn(msg, `zero found: ${Number(r.json.zero_deg).toFixed(3)}°${r.json.zero_sigma_deg === null ? "" : ` ± ${Number(r.json.zero_sigma_deg).toFixed(3)}°`}, now in force`);
  refreshRig();
});

// Which recent plan took each capture and queued each reconstruction, so
// that their rows say so (issue 38: nothing tied them to their plan).
const planOf = { captures: new Map(), reconstructions: new Map() };
function planMark(plan) {
  return plan === undefined ? "" : el("span", { class: "plan-mark", title: "taken by this plan (see the plans list)" }, ` · plan ${plan}`);
}

// Records the plans' captures and reconstructions and redraws the rows
// whose plan became known.
function notePlans(plans) {
  const captures = new Map();
  const reconstructions = new Map();
  for (const p of plans) {
    p.captures.forEach((c) => captures.set(c.capture, p.id));
    p.interim.forEach((r) => reconstructions.set(r.reconstruction, p.id));
    if (p.reconstruction !== null && p.reconstruction !== undefined) reconstructions.set(p.reconstruction, p.id);
  }
  const redraw = (kind, next, old, draw) => next.forEach((plan, id) => {
    if (old.get(id) === plan) return;
    old.set(id, plan);
    const json = seen.get(`${kind}-${id}`);
    if (json) draw(JSON.parse(json), true);
  });
  redraw("capture", captures, planOf.captures, upsertCapture);
  redraw("reconstruction", reconstructions, planOf.reconstructions, upsertReconstruction);
}

// Recent plans, each with its own Continue and Cancel, and a badge in the
// header (and the window's title) while any waits for the operator: a
// waiting plan cannot hide behind a newer one (issue 38).
// With `show`, the plan panel shows one waiting for the operator, else the
// newest (a reload then finds a waiting plan behind a newer queued one).
const PLANS_LISTED = 20;
async function loadPlans(show) {
  const r = await api("GET", `/plans?limit=${PLANS_LISTED}`);
  if (r.status !== 200) return;
  $("#plans tbody").replaceChildren(...r.json.map(planRow));
  notePlans(r.json);
  const waiting = r.json.filter((p) => p.state === "waiting_for_operator");
  if (show && r.json.length) await showPlan((waiting[0] || r.json[0]).id);
  const badge = $("#plan-badge");
  badge.hidden = waiting.length === 0;
  text(badge, waiting.length ? `plan ${waiting.map((p) => p.id).join(", ")} waiting for you` : "");
  document.title = waiting.length ? `(plan ${waiting[0].id} waiting) polnlos` : "polnlos";
}

function planRow(p) {
  const actions = el("td", {});
  if (p.state === "waiting_for_operator") {
    const b = el("button", { type: "button", class: "plan-continue", "data-plan": String(p.id) }, "Continue");
    b.addEventListener("click", () => planAction(p.id, "continue"));
    actions.append(b);
  }
  if (["queued", "running", "waiting_for_operator"].includes(p.state)) {
    const b = el("button", { type: "button", class: "plan-cancel", "data-plan": String(p.id) }, "Cancel");
    b.addEventListener("click", () => planAction(p.id, "cancel"));
    actions.append(b);
  }
  return el("tr", { id: `plan-row-${p.id}`, class: p.state },
    el("td", {}, String(p.id)), el("td", {}, p.scene), el("td", { class: "state" }, p.state.replaceAll("_", " ")),
    el("td", {}, String(p.step + 1)), el("td", { class: "prompt" }, p.state === "waiting_for_operator" ? (p.prompt || "") : ""),
    actions);
}

async function planAction(id, what) {
  const r = what === "continue" ? await api("POST", `/plans/${id}/continue`) : await api("DELETE", `/plans/${id}`);
  if (r.status >= 400 || r.status === 0) alertIn($("#plan-message"), (r.json && r.json.detail) || `HTTP ${r.status}`);
  showPlan(id);
  loadPlans();
}

$("#plan-continue").addEventListener("click", async () => {
  const r = await api("POST", `/plans/${shownPlan}/continue`);
  if (r.status >= 400) alertIn($("#plan-message"), (r.json && r.json.detail) || `HTTP ${r.status}`);
  showPlan(shownPlan);
});
$("#plan-cancel").addEventListener("click", async () => {
  const r = await api("DELETE", `/plans/${shownPlan}`);
  if (r.status >= 400) alertIn($("#plan-message"), (r.json && r.json.detail) || `HTTP ${r.status}`);
  showPlan(shownPlan);
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

function showColour(c) {
  const rows = [["scene", c.scene], ["field capture", c.capture], ["reference", c.reference], ["wall elements", c.rows]];
  c.colours.forEach((k) => rows.push([k.colour, `${fmt(k.ratio, 4)} ± ${fmt(k.sigma, 2)} of ${c.reference}` + (k.gain ? `, gain ${fmt(k.gain, 4)}` : "")]));
  (c.warnings || []).forEach((m) => rows.push(["warning", m]));
  $("#colour-result").replaceChildren(rowsTable(rows));
}

$("#colour-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const f = new FormData(ev.target);
  const capture = Number(String(f.get("capture") || "").trim() || NaN);
  if (!Number.isInteger(capture)) {
    refused("#colour-message", "#colour-result", "give the id of a capture of a white or grey field");
    return;
  }
  await fit("#fit-colour", "#colour-message", "#colour-result", "/calibrations/colour", { capture }, showColour);
});

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

// The geometry fit runs as a job (minutes on a large wall): its progress
// comes on /events, its end is read back from /calibrations/scene/{id}.
let geometryJob = null;

function fitGeometryOf(c) {
  const form = $("#geometry-form");
  form.querySelector("[name=scene]").value = c.scene;
  form.querySelector("[name=captures]").value = String(c.id);
  form.scrollIntoView();
  form.requestSubmit();
}

$("#geometry-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const form = ev.target;
  const body = fields("#geometry-message", () => ({
    scene: form.querySelector("[name=scene]").value,
    captures: captureIds(form, "captures"),
  }));
  if (!body) return;
  const free = form.querySelector("[name=free]").value.split(/[ ,]+/).filter((x) => x);
  if (free.length) body.free = free;
  const known = form.querySelector("[name=known]").value.trim();
  if (known) body.known = known;
  const msg = $("#geometry-message");
  msg.className = "message";
  $("#fit-geometry").disabled = true;
  const r = await api("POST", "/calibrations/scene", body);
  if (r.status !== 202) {
    $("#fit-geometry").disabled = false;
    refused("#geometry-message", "#geometry-result", (r.json && r.json.detail) || `HTTP ${r.status}`);
    return;
  }
  geometryJob = r.json.job;
  text(msg, `fitting (${r.json.job})…`);
  $("#geometry-result").replaceChildren();
  for (;;) {
    await new Promise((res) => setTimeout(res, 1000));
    const g = await api("GET", `/calibrations/scene/${r.json.id}`);
    if (g.status === 404) { $("#fit-geometry").disabled = false; refused("#geometry-message", "#geometry-result", g.json.detail); return; }
    if (g.status !== 200 || active(g.json.state)) continue;
    $("#fit-geometry").disabled = false;
    geometryJob = null;
    if (g.json.state === "done") { text(msg, `fitted: later reconstructions of ${g.json.scene} use it`); showGeometry(g.json); }
    else refused("#geometry-message", "#geometry-result", `${g.json.state}: ${g.json.error || ""}`);
    return;
  }
});

function geometryEvent(v) {
  if (v.type === "scene_fit" && v.job === geometryJob) {
    text($("#geometry-message"), `fitting (${v.job}): ${v.builds} T builds of at most ${v.max_builds}`);
  }
}

function showGeometry(g) {
  const f = g.fit;
  const rows = [["scene", g.scene], ["captures", g.captures.join(", ")], ["scene calibration", g.id]];
  f.fitted.forEach((x) => {
    const deg = x.freedom.endsWith("yaw");
    const v = (m) => deg ? `${fmt(m, 3)}°` : `${fmt(1e3 * m, 3)} mm`;
    rows.push([x.freedom, `${v(x.offset)} ± ${v(x.uncertainty)}`]);
  });
  const fall = 100 * (f.misfit_fitted / f.misfit_as_written - 1);
  rows.push(["misfit", `${fmt(f.misfit_as_written, 4)} → ${fmt(f.misfit_fitted, 4)} (${fall.toFixed(1)} %)`],
    ["T builds", `${f.evaluations} in ${fmt(f.seconds, 3)} s`]);
  (f.messages || []).forEach((m) => rows.push(["warning", m]));
  const file = new Blob([g.placed_toml], { type: "application/toml" });
  const link = el("a", { href: URL.createObjectURL(file), download: `${g.scene}-placed.toml`, id: "geometry-download" }, "download the placed scene file");
  const back = twoStep("Back to the file's geometry", "Really?", async () => {
    const r = await api("DELETE", `/calibrations/scene/${g.id}`);
    if (r.status === 204) { text($("#geometry-message"), `scene calibration ${g.id} deleted: ${g.scene} serves its file's geometry again (or an older fit's)`); $("#geometry-result").replaceChildren(); }
    else refused("#geometry-message", "#geometry-result", (r.json && r.json.detail) || `HTTP ${r.status}`);
  });
  $("#geometry-result").replaceChildren(rowsTable(rows), el("div", { class: "fit" }, link, " ", back));
}

async function loadScenes() {
  const r = await api("GET", "/scenes");
  if (r.status !== 200) {
    text($("#health"), tokenReason() || `scene list: HTTP ${r.status}`);
    return;
  }
  // A scene file that does not load is listed, not chosen, with its error.
  const names = r.json.filter((x) => x.error === null).map((x) => x.name);
  const broken = r.json.filter((x) => x.error !== null);
  document.querySelectorAll("select.scenes").forEach((s) => {
    s.replaceChildren(
      ...names.map((n) => el("option", { value: n }, n)),
      ...broken.map((x) => el("option", { value: "", disabled: "", title: x.error }, `${x.name} (not loaded: ${x.error})`)),
    );
    s.value = names.includes("brewster-crossed") ? "brewster-crossed" : names[0];
  });
}

// The solvers, as the daemon declares them (its OpenAPI document's Solver
// enum, public like the page): a new solver shows here without a page change.
async function loadSolvers() {
  const r = await fetch("/openapi.json", { cache: "no-store" });
  if (!r.ok) return;
  const doc = await r.json();
  const names = (((doc.components || {}).schemas || {}).Solver || {}).enum || [];
  const s = $("#reconstruction-form select[name=solver]");
  s.replaceChildren(...names.map((n) => el("option", { value: n }, n)));
  if (names.length) s.value = names[0];
}

loadScenes();
loadSolvers();
resync();
events();
applyZoom();
setInterval(resync, 15000);
// The live view: one frame a second while it is on and the tab is visible.
setInterval(() => {
  if ($("#live-on").checked && document.visibilityState === "visible") refreshLive();
}, 1000);
