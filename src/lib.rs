//! polnlos: polarization-enhanced passive non-line-of-sight imaging.
//!
//! A camera looks at a rough wall through a linear polarizer set near the
//! Brewster angle; a hidden scene lights the wall. The wall image is linear in
//! the hidden radiance, `i = T l` (MODEL.md Eq. 2); polnlos builds `T` from a
//! scene file and recovers `l` with ADMM-TV (Eq. 12).
//!
//! # Layout
//!
//! In layers, each using only the ones above it:
//!
//! - **Core** (pure maths, no I/O): [`optics`] (Fresnel, GGX, polarizer
//!   axis), [`scene`] (scene files, geometry, validation), [`transport`]
//!   (building `T`), [`solve`] (reconstruction, conditioning, metrics, λ),
//!   [`simulate`] (noise model, patterns), [`measure`] (frames to `i`,
//!   exposure planning), [`calibrate`] (homographies from target images),
//!   and [`integral`] (whole numbers in requests, `1` or `1.0`: the
//!   solver's parameters and the daemon's bodies read them alike).
//! - **I/O**: [`files`] (npy, PNG/TIFF, JSON, atomic writes, free disk and
//!   memory), [`camera`] (the camera trait, settings and sensor limits, the
//!   Aravis driver and its thread, the fake bench), [`rig`] (the bench's
//!   devices beside the camera: the rotation mount, the camera stage, the
//!   light relay, their drivers, simulated devices and services, behind one
//!   `Rig`), [`store`] (the catalogue and capture files).
//! - **Service**: [`daemon`] (its `runtime`, `requests`, `jobs` and
//!   `procedures`; no HTTP) and [`api`] (the HTTP routes, guard and server loop over it).
//!   With [`camera`], [`rig`] and [`store`] they are the cargo feature `daemon` (on by
//!   default): without it the crate is the core, [`files`] and the offline
//!   tools, and links no system library (`tests/core/layers.rs` holds `cargo
//!   tree` to that).
//! - **Reports**: `report` (the reports of `polnlos bench`; cargo feature
//!   `report`, on by default, off the daemon's path).
//!
//! # Where a change goes
//!
//! - **A pixel format** (1 file): one variant in `src/camera/pixel.rs` (its
//!   name, buffer layout and, for a polarization camera's raw mosaic, its
//!   pattern); requests, the catalogue and the driver read it from there.
//! - **A solver** (1 file and 1 line): its file in `src/solve/solvers/`, a
//!   unit struct implementing `Method` (its name, one line on it, what it
//!   needs: the Gram, a λ from the noise, a warm start; and its solve), and
//!   its line in `Solver::ALL` (`src/solve/solvers/mod.rs`). The CLI's
//!   `--solver` and its help, the API's `solver` enum (and so the page's
//!   list and Python), the automatic λ, warm starts, the report and the
//!   suite's every-solver tests take it from there; `tests/core/layers.rs`
//!   fails on a solve anywhere else in `src/` that calls a solver's entry
//!   point instead of `Solver::run` / `Solver::solve`.
//! - **A solver's parameter** (2 files): its field in `SolveRequest`
//!   (`src/solve/solvers/request.rs`: doc comment for the API, `#[arg]` for
//!   the CLI, range in `check`), read in the solver's `Method::solve` in its
//!   own file. `POST /reconstructions`, a
//!   plan's `reconstruct`, the stored parameters and the CLI's `reconstruct`
//!   embed `SolveRequest`; `tests/core/layers.rs` holds them to that.
//! - **A route**: a handler with `#[utoipa::path]` in its resource's file
//!   under `src/api/routes/` and one `routes!` line in `src/api/mod.rs`;
//!   the tests read it from
//!   `/openapi.json` (docs/guide.md, "Adding a route"). A request body the
//!   daemon checks goes in `src/daemon/requests/mod.rs`.
//! - **A write route** (a request that stores or queues something; 5 files
//!   and a line or two): its body in `src/daemon/requests/mod.rs` (`Deserialize`
//!   with `deny_unknown_fields`, `ToSchema`: its doc comments are the API's);
//!   its check in `src/daemon/requests/validate/<resource>.rs`, a pure
//!   function from the body and what the daemon knows (the scene, the
//!   captures) to a typed request, each refusal a `RequestError` that names
//!   the field; the `Admission` method that stores and queues it, which
//!   the handler reaches as `d.requests()` (`src/daemon/requests/admission.rs`:
//!   queue bounds, disk room and the camera's state are checked there, for
//!   the route and a plan alike); its re-export in `src/api/bodies.rs`; its
//!   handler in `src/api/routes/<resource>.rs` (`#[utoipa::path]` with
//!   every answer, `ApiJson<Body>`, one call to the handle, `accepted`); and
//!   its line in `all_routes` (`src/api/mod.rs`). The guard (token, body
//!   size), the error bodies, `/openapi.json`, the fuzzers and the hostile
//!   tests take it from there; a new kind of job adds its worker under
//!   `src/daemon/jobs/`. A body with a `scene` adds its name to the list in
//!   `api::openapi::with_names`, so that the document enumerates the scenes
//!   the daemon has. `tests/core/layers.rs` counts the files that name
//!   `POST /reconstructions`'s body.
//! - **A bench report**: its file in `src/report/` implementing
//!   `report::Report`, and one entry in `BenchSelection::run` (`src/report/selection.rs`,
//!   the one file that names every report).
//! - **A camera setting** (3 files, counted in docs/guide.md "Where a
//!   change goes"): its field in `Acquisition` and `CameraSettings` with
//!   its line in their `over`, `complete` and `defaults_at`
//!   (`src/camera/settings.rs`), its feature in the device mapping
//!   (`src/camera/aravis.rs`), and its `data-setting` input on the page
//!   (`web/index.html`). A setting with a range the camera reports (gain,
//!   a black level) is 2 files: its entry in `settings::RANGED` (name,
//!   features, ranges; its field in `CameraRanges`) replaces the device
//!   mapping, and the request checks, the Aravis driver and the synthetic
//!   camera read it from there. The capture request and `PUT /camera/settings`
//!   embed `CameraSettings`, the catalogue stores it as one versioned
//!   document, and the API's records, the frame files and the page's camera
//!   table all take it from there; `tests/core/layers.rs` holds the request, the
//!   camera and the store to those two declarations.
//! - **A catalogue column** (3 files): its declaration in
//!   `src/store/schema.rs` (`SCHEMA`, and `ADDED_CAPTURE_COLUMNS` for
//!   catalogues that predate it), the row type in `src/store/records.rs`,
//!   and the statements of its aggregate (`src/store/captures.rs` or
//!   `reconstructions.rs`). The row readers name each column (`SELECT *`,
//!   `r.get("kind")`), never its position; `tests/core/layers.rs` counts.
//!   Statements on either job table are written out per table in
//!   `store::Table`; none splices a table name.
//! - **A bench device** (a shutter, a second stage): its driver beside
//!   `src/rig/mount/` (a trait, the serial device, a simulated one, and its
//!   `service.rs`), and the `Rig` method a capture or a plan asks
//!   (`src/rig/mod.rs`); the capture worker names no device.
//! - **State the daemon keeps**: a service in its own file under
//!   `src/daemon/runtime/` that owns the state and its lock (as `queue.rs`,
//!   `registry.rs` and `camera.rs` do); `Daemon` holds it, and a worker gets
//!   it through `JobContext` (`src/daemon/jobs/mod.rs`) or its own struct,
//!   never the whole `Daemon` (`tests/core/layers.rs` holds this). The plan
//!   runner holds `Plans` (`src/daemon/procedures/plans.rs`), which posts its captures
//!   and reconstructions through `Admission` (`src/daemon/requests/admission.rs`),
//!   the handle a request's admission, a cancel, a delete and live view's
//!   start and stop go through. The API reaches the handles from `Daemon`
//!   (`requests()`, `plans()`, `procedures()` for the calibrations and the
//!   mount's zero, `scenes()`, `rig()`, `camera()`, `store()`, `live()`);
//!   `Daemon`'s own methods are its start and stop, the event stream and
//!   the metrics' samples.

#![deny(missing_docs)]

#[cfg(feature = "daemon")]
pub mod api;
pub mod calibrate;
#[cfg(feature = "daemon")]
pub mod camera;
#[cfg(feature = "daemon")]
pub mod daemon;
pub mod files;
pub mod integral;
pub mod measure;
pub mod optics;
#[cfg(feature = "report")]
pub mod report;
#[cfg(feature = "daemon")]
pub mod rig;
pub mod scene;
pub mod simulate;
pub mod solve;
pub mod stop;
#[cfg(feature = "daemon")]
pub mod store;
pub mod transport;
