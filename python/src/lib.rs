//! polnlos's numeric core for Python: scenes, `T`, simulation, measurement
//! and reconstruction with NumPy arrays in and out.
//!
//! Why: lab users script experiments in Python; these bindings call the very
//! functions `polnlos transport`, `simulate`, `measure` and `reconstruct`
//! call, so a script and the CLI agree to the last bit. The heavy calls
//! release the GIL.

use std::path::Path;

use numpy::ndarray::{ArrayView3, Axis};
use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2,
    PyReadonlyArrayDyn, PyUntypedArrayMethods,
};
use pyo3::create_exception;
use pyo3::exceptions::{PyException, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use polnlos::measure::given::{measure_given, GivenCapture, UnitsWanted};
use polnlos::measure::FrameStack;
use polnlos::scene::{Channel, WallSampling};
use polnlos::simulate::{unpolarized_peak, NoiseModel};
use polnlos::solve::lambda::NoiseLevel;
use polnlos::solve::scene::{reconstruct_scene, SceneInput};
use polnlos::solve::Conditioning;
use polnlos::solve::{SolveRequest, Solver};
use polnlos::transport::MemoryBudget;

create_exception!(
    _polnlos,
    PolnlosError,
    PyException,
    "An error polnlos reports: its message names the input that was wrong."
);
create_exception!(
    _polnlos,
    SceneError,
    PolnlosError,
    "A scene file that cannot be read or is invalid: the message names the key."
);

/// The memory `T` and its factorizations may take (the CLI's default).
const BUDGET: MemoryBudget = MemoryBudget::DEFAULT;

fn polnlos_err(e: impl std::fmt::Display) -> PyErr {
    PolnlosError::new_err(e.to_string())
}

fn bad(msg: impl Into<String>) -> PyErr {
    PyValueError::new_err(msg.into())
}

/// A validated scene: a bench's wall, hidden scene and camera poses.
#[pyclass(frozen, module = "polnlos")]
struct Scene {
    inner: polnlos::scene::Scene,
    name: String,
}

#[pymethods]
impl Scene {
    /// Loads a scene file, or a built-in scene by name when no such file
    /// exists (`brewster-crossed-3x3`, as the daemon and the CLI know them).
    #[staticmethod]
    fn load(name_or_path: &str) -> PyResult<Self> {
        let path = Path::new(name_or_path);
        let inner = polnlos::scene::Scene::load_or_builtin(path)
            .map_err(|e| SceneError::new_err(e.to_string()))?;
        let name = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "scene".into());
        Ok(Self { inner, name })
    }

    /// Parses a scene from TOML text (the scene-file schema of MODEL.md).
    #[staticmethod]
    #[pyo3(signature = (text, name = "scene"))]
    fn from_toml(text: &str, name: &str) -> PyResult<Self> {
        let inner = polnlos::scene::Scene::from_toml_str(text)
            .map_err(|e| SceneError::new_err(e.to_string()))?;
        Ok(Self {
            inner,
            name: name.to_string(),
        })
    }

    /// The scene's name: its file stem, or the built-in name.
    #[getter]
    fn name(&self) -> &str {
        &self.name
    }

    /// Rows of `T`: wall elements times blocks.
    #[getter]
    fn rows(&self) -> usize {
        self.inner.rows()
    }

    /// Columns of `T`: hidden-scene elements.
    #[getter]
    fn cols(&self) -> usize {
        self.inner.cols()
    }

    /// The hidden scene's grid as (rows, columns): an image's shape.
    #[getter]
    fn scene_shape(&self) -> (usize, usize) {
        let g = self.inner.hidden().plane.grid;
        (g.nv, g.nu)
    }

    /// The wall's grid as (rows, columns).
    #[getter]
    fn wall_shape(&self) -> (usize, usize) {
        let g = self.inner.wall().plane.grid;
        (g.nv, g.nu)
    }

    /// The pose names, in file order.
    #[getter]
    fn poses(&self) -> Vec<String> {
        self.inner.poses().iter().map(|p| p.name.clone()).collect()
    }

    /// The blocks of `T`'s rows in order, as labels (`A-pol0`, `B-nopol`,
    /// `A-mosaic45`).
    #[getter]
    fn blocks(&self) -> Vec<String> {
        polnlos::transport::blocks_of(&self.inner)
            .iter()
            .map(|b| b.label())
            .collect()
    }

    /// The same scene with these sampling keys set (`[wall] sampling`,
    /// `[wall] supersample`, `[scene] supersample`): how a report's `model`
    /// (what a reconstruction chose from the noise) is reproduced offline.
    #[pyo3(signature = (sampling = None, wall_supersample = None, scene_supersample = None))]
    fn with_sampling(
        &self,
        sampling: Option<&str>,
        wall_supersample: Option<usize>,
        scene_supersample: Option<usize>,
    ) -> PyResult<Self> {
        let sampling = sampling
            .map(|name| {
                WallSampling::from_name(name).ok_or_else(|| {
                    bad(format!(
                        "sampling {name:?} is not \"uniform\" or \"pixels\""
                    ))
                })
            })
            .transpose()?;
        let inner = self
            .inner
            .clone()
            .edit(|p| {
                if let Some(s) = sampling {
                    p.wall.sampling = s;
                }
                if let Some(m) = wall_supersample {
                    p.wall.plane.supersample = m;
                }
                if let Some(m) = scene_supersample {
                    p.hidden.plane.supersample = m;
                }
            })
            .map_err(|e| SceneError::new_err(e.to_string()))?;
        Ok(Self {
            inner,
            name: self.name.clone(),
        })
    }

    /// The transport matrix `T` (rows, cols), as `polnlos transport` writes it.
    fn transport<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let (rows, cols, data) = py
            .allow_threads(|| {
                polnlos::transport::build(&self.inner, BUDGET)
                    .map(|t| (t.rows(), t.cols(), t.to_row_major()))
            })
            .map_err(polnlos_err)?;
        data.into_pyarray(py).reshape([rows, cols])
    }

    fn __repr__(&self) -> String {
        format!(
            "Scene({:?}: T {} x {}, blocks {})",
            self.name,
            self.inner.rows(),
            self.inner.cols(),
            self.blocks().join(" ")
        )
    }
}

/// The conditioning of a matrix: its singular values, κ and numerical rank,
/// as `polnlos cond --json` reports them for `T`.
#[pyfunction]
fn cond<'py>(py: Python<'py>, t: PyReadonlyArray2<'py, f64>) -> PyResult<Bound<'py, PyDict>> {
    let (rows, cols) = (t.shape()[0], t.shape()[1]);
    if rows == 0 || cols == 0 {
        return Err(bad(format!(
            "T is {rows} x {cols}; give a matrix with at least one row and column"
        )));
    }
    let view = t.as_array();
    if let Some(x) = view.iter().find(|x| !x.is_finite()) {
        return Err(bad(format!("T holds {x}; every entry must be finite")));
    }
    let m = faer::Mat::<f64>::from_fn(rows, cols, |i, j| view[[i, j]]);
    let c = py
        .allow_threads(|| {
            m.singular_values()
                .map(|s| Conditioning::from_singular_values(rows, cols, s))
        })
        .map_err(|e| polnlos_err(format!("the SVD of T did not converge ({e:?})")))?;
    let d = PyDict::new(py);
    d.set_item("rows", c.rows)?;
    d.set_item("cols", c.cols)?;
    d.set_item("kappa", c.kappa)?;
    d.set_item("rank", c.rank)?;
    d.set_item("threshold", c.threshold)?;
    d.set_item("singular_values", c.singular_values.into_pyarray(py))?;
    Ok(d)
}

/// A hidden-scene image as a flat vector in `scene`'s element order: an
/// `(nv, nu)` array is an image top row first (+v up), `nv * nu` values
/// are the element order itself.
fn image_on(scene: &Scene, image: &PyReadonlyArrayDyn<'_, f64>, what: &str) -> PyResult<Vec<f64>> {
    let (nv, nu) = scene.scene_shape();
    let shape = image.shape();
    if shape != [nv, nu] && shape != [nv * nu] {
        return Err(bad(format!(
            "{what} has shape {shape:?}; scene {:?} needs ({nv}, {nu}) (or {} values)",
            scene.name,
            nv * nu
        )));
    }
    let v: Vec<f64> = image.as_array().iter().copied().collect();
    if let Some(x) = v.iter().find(|x| !x.is_finite()) {
        return Err(bad(format!("{what} holds {x}; every value must be finite")));
    }
    Ok(match shape.len() {
        2 => scene.inner.hidden().plane.grid.from_top_first(&v, 1),
        _ => v,
    })
}

/// A simulated measurement of `truth` (radiance in [0, 1] on the scene grid)
/// through `scene`'s `T` and a camera: returns `(measurement, info)`, as
/// `polnlos simulate` writes `measurement.npy` and `simulate.json`; `info`
/// also holds the camera model's `variance` of each value.
#[pyfunction]
#[pyo3(signature = (scene, truth, photons = NoiseModel::default().photons, read_noise = NoiseModel::default().read_noise, bits = NoiseModel::default().bits, seed = NoiseModel::default().seed))]
fn simulate<'py>(
    py: Python<'py>,
    scene: &Scene,
    truth: PyReadonlyArrayDyn<'py, f64>,
    photons: f64,
    read_noise: f64,
    bits: u32,
    seed: u64,
) -> PyResult<(Bound<'py, PyArray1<f64>>, Bound<'py, PyDict>)> {
    let truth = image_on(scene, &truth, "truth")?;
    let model = NoiseModel {
        photons,
        read_noise,
        bits,
        seed,
    };
    model.validate().map_err(|e| bad(e.to_string()))?;
    let (sim, peak) = py
        .allow_threads(|| -> Result<_, String> {
            let t = polnlos::transport::build(&scene.inner, BUDGET).map_err(|e| e.to_string())?;
            let peak =
                unpolarized_peak(&scene.inner, &t, &truth, BUDGET).map_err(|e| e.to_string())?;
            let sim = model
                .apply(t.apply(&truth), peak)
                .map_err(|e| e.to_string())?;
            Ok((sim, peak))
        })
        .map_err(polnlos_err)?;
    let info = PyDict::new(py);
    info.set_item("photons", photons)?;
    info.set_item("read_noise", read_noise)?;
    info.set_item("bits", bits)?;
    info.set_item("seed", seed)?;
    info.set_item("unpolarized_peak", peak)?;
    info.set_item("electrons_per_unit", sim.electrons_per_unit)?;
    info.set_item("units_per_dn", sim.units_per_dn)?;
    // The variance of each value under the camera model, for reconstruct's
    // automatic λ (as `polnlos reconstruct --noise-from simulate.json`).
    let noise = NoiseLevel::from_camera(
        &sim.measurement,
        sim.electrons_per_unit,
        read_noise,
        sim.units_per_dn,
    );
    info.set_item("variance", noise.variance.into_pyarray(py))?;
    Ok((sim.measurement.into_pyarray(py), info))
}

/// Frames as a stack: a (frames, height, width) or (height, width) array of
/// uint8, uint16, float32 or float64 values in DN; its full scale for
/// integers when none is given.
fn stack_of(frames: &Bound<'_, PyAny>, what: &str) -> PyResult<(FrameStack, Option<f64>)> {
    fn push<T: Copy + Into<f64> + numpy::Element>(
        a: PyReadonlyArrayDyn<'_, T>,
        what: &str,
    ) -> PyResult<FrameStack> {
        let view = a.as_array();
        let view: ArrayView3<'_, T> = match view.ndim() {
            2 => view.insert_axis(Axis(0)).into_dimensionality(),
            3 => view.into_dimensionality(),
            n => {
                return Err(bad(format!(
                    "{what} has {n} dimensions; give (frames, height, width) or one (height, width) frame"
                )))
            }
        }
        .map_err(|e| bad(format!("{what}: {e}")))?;
        let (n, h, w) = view.dim();
        if n == 0 || h == 0 || w == 0 {
            return Err(bad(format!(
                "{what} is {n} frames of {w}x{h}; give at least one frame of at least one pixel"
            )));
        }
        let mut stack = FrameStack::new(w, h);
        let mut row = Vec::with_capacity(w * h);
        for frame in view.outer_iter() {
            row.clear();
            row.extend(frame.iter().copied());
            stack.push(&row);
        }
        Ok(stack)
    }
    if let Ok(a) = frames.extract::<PyReadonlyArrayDyn<'_, u16>>() {
        return Ok((push(a, what)?, Some(65535.0)));
    }
    if let Ok(a) = frames.extract::<PyReadonlyArrayDyn<'_, u8>>() {
        return Ok((push(a, what)?, Some(255.0)));
    }
    if let Ok(a) = frames.extract::<PyReadonlyArrayDyn<'_, f32>>() {
        return Ok((push(a, what)?, None));
    }
    if let Ok(a) = frames.extract::<PyReadonlyArrayDyn<'_, f64>>() {
        return Ok((push(a, what)?, None));
    }
    Err(bad(format!(
        "{what} must be a NumPy array of uint8, uint16, float32 or float64 frames"
    )))
}

/// The analyzer a capture was taken through: degrees from crossed, `"none"`
/// or `"mosaic"`.
fn channels_of(angle: &Bound<'_, PyAny>) -> PyResult<Vec<Channel>> {
    let text = match angle.extract::<f64>() {
        Ok(deg) => deg.to_string(),
        Err(_) => angle
            .extract::<String>()
            .map_err(|_| bad("angle must be degrees from crossed, \"none\" or \"mosaic\""))?,
    };
    Channel::of_capture(&text).map_err(|e| bad(e.to_string()))
}

/// `(i, variance or None, info)` as Python receives them.
type Measured<'py> = (
    Bound<'py, PyArray1<f64>>,
    Option<Bound<'py, PyArray1<f64>>>,
    Bound<'py, PyDict>,
);

/// Captures' frames measured into the scene's `i`: returns `(measurement,
/// variance or None, info)`, as `polnlos measure` writes them.
///
/// `captures` is a list of dicts with keys `frames`, `pose`, `angle`,
/// `exposure_us` and optionally `dark` and `full_scale`, one per capture.
#[pyfunction]
#[pyo3(signature = (scene, captures, gain = None, raw = false))]
fn measure_captures<'py>(
    py: Python<'py>,
    scene: &Scene,
    captures: Vec<Bound<'py, PyDict>>,
    gain: Option<f64>,
    raw: bool,
) -> PyResult<Measured<'py>> {
    if captures.is_empty() {
        return Err(bad("give at least one capture"));
    }
    let mut given = Vec::with_capacity(captures.len());
    for (k, c) in captures.iter().enumerate() {
        let name = format!("capture {k}");
        let get = |key: &str| -> PyResult<Bound<'py, PyAny>> {
            c.get_item(key)?
                .ok_or_else(|| bad(format!("{name} has no {key:?}")))
        };
        let (stack, default_full) = stack_of(&get("frames")?, &format!("{name}'s frames"))?;
        let dark = match c.get_item("dark")? {
            Some(d) if !d.is_none() => Some(stack_of(&d, &format!("{name}'s dark"))?.0),
            _ => None,
        };
        let full_scale = match c.get_item("full_scale")? {
            Some(f) if !f.is_none() => f.extract::<f64>()?,
            _ => default_full.ok_or_else(|| {
                bad(format!(
                    "{name}'s frames are floats: give its full_scale in DN (e.g. 65535)"
                ))
            })?,
        };
        if !(full_scale.is_finite() && full_scale > 0.0) {
            return Err(bad(format!(
                "{name}: full_scale {full_scale} must be positive"
            )));
        }
        let exposure_us: f64 = get("exposure_us")?.extract()?;
        if !(exposure_us.is_finite() && exposure_us > 0.0) {
            return Err(bad(format!(
                "{name}: exposure_us {exposure_us} must be positive"
            )));
        }
        given.push(GivenCapture::new(
            name.clone(),
            get("pose")?.extract()?,
            channels_of(&get("angle")?)?,
            stack,
            dark,
            full_scale,
            exposure_us,
            "give dark frames (scene off, same exposure and region) as dark=",
        ));
    }
    let wanted = match (raw, gain) {
        (true, _) => UnitsWanted::Raw,
        (false, Some(g)) => UnitsWanted::Gain(g),
        (false, None) => UnitsWanted::Estimated,
    };
    let mut warnings = Vec::new();
    let mut measured = py
        .allow_threads(|| {
            measure_given(&scene.inner, &given, wanted, BUDGET, &|_| {}, &mut warnings)
        })
        .map_err(|e| {
            // What the user should also know travels with the error.
            let also: String = warnings.iter().map(|w| format!("\n(also: {w})")).collect();
            polnlos_err(format!("{e}{also}"))
        })?;
    let info = PyDict::new(py);
    let labels: Vec<String> = measured.blocks.iter().map(|b| b.label()).collect();
    info.set_item("blocks", labels)?;
    info.set_item(
        "units",
        match measured.channels[0].1 {
            None => "fractions of full scale per microsecond".to_string(),
            Some(u) => format!("units of T l (divided by {:.6e})", u.factor()),
        },
    )?;
    info.set_item("warnings", warnings)?;
    // Frames given from Python have no Bayer filter: one grey channel.
    let (m, _) = measured.channels.swap_remove(0);
    Ok((
        m.i.into_pyarray(py),
        m.variance.map(|v| v.into_pyarray(py)),
        info,
    ))
}

/// Reconstructs the hidden scene from `measurement`: returns `(image,
/// report)`, the image on the scene grid and the report `polnlos
/// reconstruct` writes as report.json.
#[pyfunction]
#[pyo3(signature = (scene, measurement, lam = None, variance = None, solver = "admm-tv", truth = None, max_iter = None, full_spectrum = false))]
#[allow(clippy::too_many_arguments)]
fn reconstruct<'py>(
    py: Python<'py>,
    scene: &Scene,
    measurement: PyReadonlyArray1<'py, f64>,
    lam: Option<f64>,
    variance: Option<PyReadonlyArray1<'py, f64>>,
    solver: &str,
    truth: Option<PyReadonlyArrayDyn<'py, f64>>,
    max_iter: Option<usize>,
    full_spectrum: bool,
) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyAny>)> {
    let solver = Solver::named(solver).ok_or_else(|| {
        bad(format!(
            "solver {solver:?} is not one of {}",
            Solver::names().join(", ")
        ))
    })?;
    let meas = measurement.as_slice()?;
    let noise = match &variance {
        Some(v) => {
            let v = v.as_slice()?;
            if v.len() != meas.len() {
                return Err(bad(format!(
                    "variance has {} values but the measurement has {}; give the variance measured with it",
                    v.len(),
                    meas.len()
                )));
            }
            if v.iter().any(|x| !(x.is_finite() && *x >= 0.0)) {
                return Err(bad("every variance must be finite and not negative"));
            }
            Some(NoiseLevel::measured(v.to_vec()))
        }
        None => None,
    };
    let truth = truth.map(|t| image_on(scene, &t, "truth")).transpose()?;
    let req = SolveRequest {
        solver,
        lambda: lam,
        max_iter,
        ..Default::default()
    };
    req.check().map_err(|e| bad(e.to_string()))?;
    let solved = py
        .allow_threads(|| {
            reconstruct_scene(
                &scene.inner,
                SceneInput {
                    measurement: meas,
                    noise,
                    truth: truth.as_deref(),
                    full_spectrum,
                    name: scene.name.clone(),
                    stop: Default::default(),
                },
                &req,
                BUDGET,
                &|_| {},
            )
        })
        .map_err(polnlos_err)?;
    let report = serde_json::to_string(&solved.report).map_err(polnlos_err)?;
    let report = py.import("json")?.call_method1("loads", (report,))?;
    let (nv, nu) = scene.scene_shape();
    let grid = scene.inner.hidden().plane.grid;
    let image = grid.to_top_first(&solved.image, 1);
    let image = image.into_pyarray(py).reshape([nv, nu])?;
    Ok((image, report))
}

/// A photo's reconstruction with its gain and background fitted, as
/// `polnlos reconstruct --photo` (docs/realphoto.md): the same function on
/// the same `T`, so the same numbers. `measurement` is `[rows]` or
/// `[rows, C]` (NaN where not measured); `truth` `[nv, nu]` (every channel)
/// or `[nv, nu, C]`, top row first. Returns the image (`[nv, nu]` or
/// `[nv, nu, C]`, top row first) and report.json as a dict.
#[pyfunction]
#[pyo3(signature = (scene, measurement, lam = None, truth = None, max_iter = None))]
fn reconstruct_photo<'py>(
    py: Python<'py>,
    scene: &Scene,
    measurement: PyReadonlyArrayDyn<'py, f64>,
    lam: Option<f64>,
    truth: Option<PyReadonlyArrayDyn<'py, f64>>,
    max_iter: Option<usize>,
) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
    use polnlos::solve::photo::{split_channels, PhotoReport, PhotoSettings};
    let shape = measurement.shape().to_vec();
    let data: Vec<f64> = measurement.as_array().iter().copied().collect();
    let channels = split_channels(&shape, &data, scene.inner.rows())
        .map_err(|e| bad(format!("measurement {e}")))?;
    let c = channels.len();
    let (nv, nu) = scene.scene_shape();
    let truth = match &truth {
        None => None,
        Some(t) if t.shape() == [nv, nu, c] && c > 1 => {
            let v: Vec<f64> = t.as_array().iter().copied().collect();
            let v = scene.inner.hidden().plane.grid.from_top_first(&v, c);
            Some(
                (0..c)
                    .map(|ch| v.iter().skip(ch).step_by(c).copied().collect())
                    .collect(),
            )
        }
        Some(t) => Some(vec![image_on(scene, t, "truth")?; c]),
    };
    if let Some(l) = lam {
        if !(l >= 0.0 && l.is_finite()) {
            return Err(bad(format!("lam {l}: must be a finite number >= 0")));
        }
    }
    let d = PhotoSettings::default();
    let settings = PhotoSettings {
        lambda: lam,
        iterations: max_iter.unwrap_or(d.iterations),
        ..d
    };
    let start = std::time::Instant::now();
    let (report, transport_seconds, shadows) = py
        .allow_threads(|| {
            let t = polnlos::transport::build(&scene.inner, BUDGET).map_err(|e| e.to_string())?;
            // As the CLI's --photo: an open shadow choice is the photo's.
            type Failure = Box<dyn std::error::Error + Send + Sync>;
            let chosen = polnlos::solve::photo::photo_transport(
                &scene.inner,
                Box::new(t),
                || -> Result<_, Failure> {
                    let area = scene.inner.with_area_shadows()?;
                    Ok(Box::new(polnlos::transport::build(&area, BUDGET)?))
                },
                &channels,
                &settings,
            )
            .map_err(|e| e.to_string())?;
            let seconds = start.elapsed().as_secs_f64();
            chosen
                .reconstruct(&channels, truth.as_deref(), &settings)
                .map(|r| (r, seconds, chosen.shadows.clone()))
                .map_err(|e| e.to_string())
        })
        .map_err(polnlos_err)?;
    let image: Vec<f64> = (0..nv * nu)
        .flat_map(|k| report.channels.iter().map(move |ch| ch.image[k]))
        .collect();
    let image = scene.inner.hidden().plane.grid.to_top_first(&image, c);
    let report = PhotoReport {
        scene: scene.name.clone(),
        radiometry: polnlos::solve::radiometry::RadiometryChoice {
            mode: polnlos::solve::radiometry::Radiometry::Fitted,
            given: true,
            reason: "asked for (radiometry=\"fitted\")".into(),
        },
        transport_seconds,
        transport_cache: None,
        shadows: Some(shadows),
        total_seconds: start.elapsed().as_secs_f64(),
        result: report,
    };
    let text = serde_json::to_string(&report).map_err(polnlos_err)?;
    let report = py.import("json")?.call_method1("loads", (text,))?;
    let image = image.into_pyarray(py);
    let image = match c {
        1 => image.reshape([nv, nu])?.into_any(),
        _ => image.reshape([nv, nu, c])?.into_any(),
    };
    Ok((image, report))
}

/// Seconds each of `repeat` runs of the Rust reconstruction takes, called
/// from Rust with no Python in between: the baseline the bindings' overhead
/// is measured against (python/benches/overhead.py).
#[pyfunction]
fn rust_reconstruct_seconds(
    py: Python<'_>,
    scene: &Scene,
    measurement: PyReadonlyArray1<'_, f64>,
    lam: f64,
    repeat: usize,
) -> PyResult<Vec<f64>> {
    let meas = measurement.as_slice()?;
    let req = SolveRequest {
        solver: Solver::ADMM_TV,
        lambda: Some(lam),
        ..Default::default()
    };
    req.check().map_err(|e| bad(e.to_string()))?;
    py.allow_threads(|| {
        (0..repeat.clamp(1, 1000))
            .map(|_| {
                let start = std::time::Instant::now();
                reconstruct_scene(
                    &scene.inner,
                    SceneInput {
                        measurement: meas,
                        name: scene.name.clone(),
                        ..Default::default()
                    },
                    &req,
                    BUDGET,
                    &|_| {},
                )
                .map(|solved| {
                    std::hint::black_box(solved);
                    start.elapsed().as_secs_f64()
                })
            })
            .collect::<Result<Vec<_>, _>>()
    })
    .map_err(polnlos_err)
}

/// Frames from TIFF bytes (a capture's `mean.tiff` or `frame.tiff` from the
/// daemon, a file): `(mean, full_scale or None)`, the mean of the pages in DN.
#[pyfunction]
fn decode_tiff<'py>(
    py: Python<'py>,
    data: &[u8],
) -> PyResult<(Bound<'py, PyArray2<f64>>, Option<f64>)> {
    let file = polnlos::files::frames::decode_frames(data).map_err(polnlos_err)?;
    let (w, h) = (file.stack.width, file.stack.height);
    let full = file.full_scale();
    let mean = file.stack.mean;
    Ok((mean.into_pyarray(py).reshape([h, w])?, full))
}

/// A test pattern (`disk`, `bars`, `letter`) on `scene`'s grid, as
/// `polnlos pattern` draws it: an image top row first.
#[pyfunction]
fn pattern<'py>(py: Python<'py>, name: &str, scene: &Scene) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let p = polnlos::simulate::patterns::Pattern::from_name(name).ok_or_else(|| {
        let names: Vec<&str> = polnlos::simulate::patterns::Pattern::ALL
            .iter()
            .map(|p| p.name())
            .collect();
        bad(format!(
            "pattern {name:?} is not one of {}",
            names.join(", ")
        ))
    })?;
    let (nv, nu) = scene.scene_shape();
    let g = scene.inner.hidden().plane.grid;
    g.to_top_first(&p.render(g), 1)
        .into_pyarray(py)
        .reshape([nv, nu])
}

/// The built-in scene names.
#[pyfunction]
fn builtin_scenes() -> Vec<&'static str> {
    polnlos::scene::builtin::BUILT_IN
        .iter()
        .map(|(n, _)| *n)
        .collect()
}

#[pymodule]
fn _polnlos(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("PolnlosError", m.py().get_type::<PolnlosError>())?;
    m.add("SceneError", m.py().get_type::<SceneError>())?;
    m.add_class::<Scene>()?;
    // The registered solvers' names, the library's own list (a new solver
    // appears here with no edit).
    m.add("SOLVERS", Solver::names())?;
    m.add_function(wrap_pyfunction!(cond, m)?)?;
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    m.add_function(wrap_pyfunction!(measure_captures, m)?)?;
    m.add_function(wrap_pyfunction!(reconstruct, m)?)?;
    m.add_function(wrap_pyfunction!(reconstruct_photo, m)?)?;
    m.add_function(wrap_pyfunction!(decode_tiff, m)?)?;
    m.add_function(wrap_pyfunction!(pattern, m)?)?;
    m.add_function(wrap_pyfunction!(builtin_scenes, m)?)?;
    m.add_function(wrap_pyfunction!(rust_reconstruct_seconds, m)?)?;
    Ok(())
}
