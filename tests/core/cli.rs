//! The `polnlos` binary end to end on the shipped scenes: every subcommand,
//! its files and JSON, and its errors for bad input.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use polnlos::files::{image, npy};
use polnlos::scene::{Grid, Scene};
use polnlos::simulate::patterns::Pattern;
use polnlos::transport::MemoryBudget;

fn scene(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(format!("config/scenes/{name}.toml"))
}

/// `polnlos args`, with no cache of built matrices (a test writes nothing
/// outside its own folders; `transport_cache_*` tests give their own).
pub(crate) fn polnlos(args: &[&str]) -> Output {
    polnlos_with_cache(args, "off")
}

/// `polnlos args` with `POLNLOS_CACHE=cache`, in the background class
/// (`crate::priority`): the CLI needs CPU time, not a core on time.
fn polnlos_with_cache(args: &[&str], cache: &str) -> Output {
    crate::priority::background();
    Command::new(env!("CARGO_BIN_EXE_polnlos"))
        .args(args)
        .env("POLNLOS_CACHE", cache)
        .output()
        .expect("run polnlos")
}

pub(crate) fn ok(out: &Output) -> String {
    assert!(
        out.status.success(),
        "stderr: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// A command that failed with exit status `code` (see `polnlos --help`); its stderr.
fn fails_with(code: i32, out: &Output) -> String {
    assert_eq!(
        out.status.code(),
        Some(code),
        "stdout {}\nstderr {}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Exit status 3: a file the user named is wrong.
fn fails(out: &Output) -> String {
    fails_with(3, out)
}

/// Exit status 2: the command line is wrong.
fn usage(out: &Output) -> String {
    fails_with(2, out)
}

#[test]
fn help_lists_the_subcommands() {
    let text = ok(&polnlos(&["--help"]));
    for cmd in ["transport", "cond", "simulate", "reconstruct", "pattern"] {
        assert!(text.contains(cmd), "{text}");
    }
    assert!(ok(&polnlos(&["simulate", "--help"])).contains("--photons"));
    // Help says what is, not when it came to be ("before the eighteenth session").
    for help in [text, ok(&polnlos(&["calibrate", "--help"]))] {
        assert!(!help.contains("th session"), "{help}");
    }
    assert!(ok(&polnlos(&["calibrate", "--help"])).contains("scene"));
}

#[test]
fn transport_writes_a_standard_npy() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("T.npy");
    let s = scene("brewster-rotating-3x3");
    ok(&polnlos(&[
        "transport",
        s.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]));
    let a = npy::read(&out).unwrap();
    assert_eq!(a.shape, vec![4096, 9]);
    let t = polnlos::transport::build(
        &polnlos::scene::Scene::load(&s).unwrap(),
        MemoryBudget::DEFAULT,
    )
    .unwrap();
    // C order: row j, column k at j * 9 + k.
    assert_eq!(a.data[1500 * 9 + 7], t.get(1500, 7));
    ok(&polnlos(&[
        "transport",
        s.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--f32",
    ]));
    let b = npy::read(&out).unwrap();
    assert!((b.data[1500 * 9 + 7] / t.get(1500, 7) - 1.0).abs() < 1e-6);

    // Adaptive supersampling: same shape, reports its levels, differs from m = 1.
    let o = polnlos(&[
        "transport",
        s.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--adaptive",
        "1e-3",
    ]);
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("adaptive supersampling: wall elements"),
        "{err}"
    );
    let c = npy::read(&out).unwrap();
    assert_eq!(c.shape, vec![4096, 9]);
    assert!(c.data.iter().zip(&a.data).any(|(x, y)| x != y));
    let msg = usage(&polnlos(&[
        "transport",
        s.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--adaptive=0",
    ]));
    assert!(msg.contains("tolerance = 0"), "{msg}");

    // The time-resolved T: rows are block x wall element x time bin.
    let o = polnlos(&[
        "transport",
        s.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--active",
        "--bin-width",
        "0.02",
    ]);
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(o.status.success(), "{err}");
    let d = npy::read(&out).unwrap();
    let bins = d.shape[0] / (4 * 1024);
    assert_eq!(d.shape, vec![4 * 1024 * bins, 9], "{err}");
    assert!((5..20).contains(&bins), "{err}");
    assert!(
        err.contains(&format!("{bins} time bins of 0.02 m")),
        "{err}"
    );
    let msg = usage(&polnlos(&[
        "transport",
        s.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--active",
        "--spot",
        "0.5,0",
    ]));
    assert!(msg.contains("spot"), "{msg}");
}

#[test]
fn builtin_scene_names_work_like_files() {
    let by_name = ok(&polnlos(&["cond", "brewster-crossed-3x3", "--json"]));
    let by_file = ok(&polnlos(&[
        "cond",
        scene("brewster-crossed-3x3").to_str().unwrap(),
        "--json",
    ]));
    let kappa = |t: &str| serde_json::from_str::<serde_json::Value>(t).unwrap()["kappa"].clone();
    assert_eq!(kappa(&by_name), kappa(&by_file));
    assert_eq!(
        serde_json::from_str::<serde_json::Value>(&by_name).unwrap()["scene"],
        "brewster-crossed-3x3"
    );
    let err = fails(&polnlos(&["cond", "brewster-nothing"]));
    assert!(err.contains("cannot read scene file"), "{err}");
}

#[test]
fn cond_json_reports_kappa_and_rank() {
    let text = ok(&polnlos(&[
        "cond",
        scene("brewster-crossed-3x3").to_str().unwrap(),
        "--json",
    ]));
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert!((v["kappa"].as_f64().unwrap() / 113.5036206092875 - 1.0).abs() < 1e-6);
    assert_eq!(v["rank"], 9);
    assert_eq!(v["singular_values"].as_array().unwrap().len(), 9);
    assert_eq!(v["blocks"][0]["pose"], "A");
}

#[test]
fn simulate_then_reconstruct_through_files() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let truth = d.join("letter.png");
    ok(&polnlos(&[
        "pattern",
        "letter",
        "--size",
        "32",
        "--out",
        truth.to_str().unwrap(),
    ]));
    let png = image::read_gray(&truth).unwrap();
    // The PNG shows the letter upright: the plane's top (+v) in row 0.
    let g32 = Grid { nu: 32, nv: 32 };
    let expect = g32.to_top_first(&Pattern::Letter.render(g32), 1);
    assert!(png
        .data
        .iter()
        .zip(&expect)
        .all(|(a, b)| (a - b).abs() < 1e-4));
    let s = scene("brewster-multi");
    let sim = d.join("sim");
    ok(&polnlos(&[
        "simulate",
        s.to_str().unwrap(),
        "--truth",
        truth.to_str().unwrap(),
        "--out",
        sim.to_str().unwrap(),
        "--photons",
        "50000",
        "--seed",
        "4",
        "--frames",
    ]));
    for f in [
        "measurement.npy",
        "truth.npy",
        "simulate.json",
        "wall-B-pol0.png",
        "wall-C-pol0.png",
        "frame-B-pol0.png",
        "frame-C-pol0.png",
    ] {
        assert!(sim.join(f).exists(), "{f} missing");
    }
    let sj: serde_json::Value =
        serde_json::from_slice(&std::fs::read(sim.join("simulate.json")).unwrap()).unwrap();
    assert_eq!(sj["rows"], 2048);
    assert_eq!(sj["noise"]["photons"], 50000.0);
    let frame = image::read_gray(&sim.join("frame-B-pol0.png")).unwrap();
    assert_eq!((frame.width, frame.height), (512, 512));
    assert_eq!(npy::read(&sim.join("truth.npy")).unwrap().shape, vec![8, 8]);

    let rec = d.join("rec");
    let args = |solver: &str, out: &PathBuf| {
        polnlos(&[
            "reconstruct",
            s.to_str().unwrap(),
            "--measurement",
            sim.join("measurement.npy").to_str().unwrap(),
            "--truth",
            sim.join("truth.npy").to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--solver",
            solver,
        ])
    };
    ok(&args("admm-tv", &rec));
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(rec.join("report.json")).unwrap()).unwrap();
    assert_eq!(r["solver"]["solver"], "admm-tv");
    assert!(r["solver"]["converged"].as_bool().unwrap());
    assert!(r["conditioning"]["kappa"].as_f64().unwrap() > 1e6);
    let psnr = r["metrics"]["psnr_db"].as_f64().unwrap();
    assert!(psnr > 12.0, "ADMM-TV PSNR {psnr}");
    let img = npy::read(&rec.join("recovered.npy")).unwrap();
    assert_eq!(img.shape, vec![8, 8]);
    assert!(img.data.iter().all(|v| (0.0..=1.0).contains(v)));
    assert_eq!(
        image::read_gray(&rec.join("recovered.png")).unwrap().width,
        8
    );

    // FISTA-TV minimizes the same objective: same lambda, PSNR within 0.5 dB of ADMM.
    let fista = d.join("fista");
    ok(&args("fista-tv", &fista));
    let f: serde_json::Value =
        serde_json::from_slice(&std::fs::read(fista.join("report.json")).unwrap()).unwrap();
    assert_eq!(f["solver"]["solver"], "fista-tv");
    assert_eq!(f["solver"]["lambda"], r["solver"]["lambda"]);
    let fpsnr = f["metrics"]["psnr_db"].as_f64().unwrap();
    assert!(
        (fpsnr - psnr).abs() < 0.5,
        "FISTA {fpsnr} dB vs ADMM {psnr} dB"
    );

    // lambda from the noise level of the simulation.
    let auto = d.join("auto");
    ok(&polnlos(&[
        "reconstruct",
        s.to_str().unwrap(),
        "--measurement",
        sim.join("measurement.npy").to_str().unwrap(),
        "--out",
        auto.to_str().unwrap(),
        "--noise-from",
        sim.join("simulate.json").to_str().unwrap(),
    ]));
    let a: serde_json::Value =
        serde_json::from_slice(&std::fs::read(auto.join("report.json")).unwrap()).unwrap();
    let c = &a["lambda_choice"];
    assert_eq!(
        c["rule"], "resolved-discrepancy",
        "no --lambda + noise = auto"
    );
    let (misfit, target, floor) = (
        c["misfit"].as_f64().unwrap(),
        c["target"].as_f64().unwrap(),
        c["floor"].as_f64().unwrap(),
    );
    assert!(floor < target && misfit <= target, "{c}");
    assert!(c["resolved"].as_u64().unwrap() >= 1);
    assert_eq!(a["solver"]["lambda"], c["lambda"]);
    assert_eq!(c["noise"], "camera-model");
    // Without a noise level, the measurement's own residual gives it.
    let alone = d.join("alone");
    let out = ok(&polnlos(&[
        "reconstruct",
        s.to_str().unwrap(),
        "--measurement",
        sim.join("measurement.npy").to_str().unwrap(),
        "--out",
        alone.to_str().unwrap(),
        "--lambda",
        "auto",
    ]));
    assert!(
        out.contains("noise from residual"),
        "results on stdout: {out}"
    );
    let b: serde_json::Value =
        serde_json::from_slice(&std::fs::read(alone.join("report.json")).unwrap()).unwrap();
    assert_eq!(b["lambda_choice"]["noise"], "residual");
    // The residual's variance is the camera model's to within 25 %.
    let ratio = b["lambda_choice"]["noise_variance"].as_f64().unwrap()
        / c["noise_variance"].as_f64().unwrap();
    assert!((0.75..1.25).contains(&ratio), "{ratio}");
    let err = usage(&polnlos(&[
        "reconstruct",
        s.to_str().unwrap(),
        "--measurement",
        sim.join("measurement.npy").to_str().unwrap(),
        "--out",
        alone.to_str().unwrap(),
        "--solver",
        "tikhonov",
        "--lambda",
        "auto",
    ]));
    // The TV solvers, named from the registry.
    assert!(
        err.contains("choose it from the noise (admm-tv, fista-tv, gp-tv)"),
        "{err}"
    );

    let rec_lsq = d.join("lsq");
    ok(&args("lsq", &rec_lsq));
    let l: serde_json::Value =
        serde_json::from_slice(&std::fs::read(rec_lsq.join("report.json")).unwrap()).unwrap();
    assert!(l["metrics"]["psnr_db"].as_f64().unwrap() < psnr);
    ok(&args("tikhonov", &d.join("tik")));
}

#[test]
fn bad_input_gets_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // A scene file with an out-of-range key.
    let bad = d.join("bad.toml");
    std::fs::write(
        &bad,
        std::fs::read_to_string(scene("brewster-crossed"))
            .unwrap()
            .replace("roughness = 0.3", "roughness = 0"),
    )
    .unwrap();
    let err = fails(&polnlos(&["cond", bad.to_str().unwrap()]));
    assert!(
        err.contains("wall.roughness = 0.0: must be in (0, 1]") && err.contains("bad.toml"),
        "{err}"
    );
    // A missing file.
    let err = fails(&polnlos(&["cond", d.join("nope.toml").to_str().unwrap()]));
    assert!(err.contains("cannot read scene file"), "{err}");
    assert_eq!(
        err.matches("os error 2").count(),
        1,
        "the OS error once: {err}"
    );
    // A measurement of the wrong length.
    let m = d.join("short.npy");
    npy::write_f64(&m, &[10], &[0.5; 10]).unwrap();
    let err = fails(&polnlos(&[
        "reconstruct",
        scene("brewster-crossed").to_str().unwrap(),
        "--measurement",
        m.to_str().unwrap(),
        "--out",
        d.join("o").to_str().unwrap(),
    ]));
    assert!(
        err.contains("measurement has 10 values but T has 1024 rows"),
        "{err}"
    );
    // A truth that is not an image.
    let junk = d.join("junk.png");
    std::fs::write(&junk, b"not a png").unwrap();
    let err = fails(&polnlos(&[
        "simulate",
        scene("brewster-crossed").to_str().unwrap(),
        "--truth",
        junk.to_str().unwrap(),
        "--out",
        d.join("s").to_str().unwrap(),
    ]));
    assert!(err.contains("junk.png"), "{err}");
    // Out-of-range noise parameters.
    let err = usage(&polnlos(&[
        "simulate",
        scene("brewster-crossed").to_str().unwrap(),
        "--truth",
        junk.to_str().unwrap(),
        "--out",
        d.join("s").to_str().unwrap(),
        "--bits",
        "20",
    ]));
    assert!(err.contains("bits = 20: must be from 1 to 16"), "{err}");
}

/// A scene file with some text replaced, written into `dir`.
fn edited_scene(dir: &std::path::Path, name: &str, edits: &[(&str, &str)]) -> PathBuf {
    let mut text = std::fs::read_to_string(scene("brewster-crossed")).unwrap();
    for (from, to) in edits {
        assert!(text.contains(from), "{from}");
        text = text.replacen(from, to, 1);
    }
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn hostile_files_get_a_named_error_not_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // An .npy header announcing 2^64 values (exit 101 before: index out of bounds).
    let mut header =
        "{'descr': '<f8', 'fortran_order': True, 'shape': (4294967296, 4294967296), }".to_string();
    while !(10 + header.len() + 1).is_multiple_of(64) {
        header.push(' ');
    }
    header.push('\n');
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
    bytes.extend_from_slice(header.as_bytes());
    bytes.extend_from_slice(&[0u8; 64]);
    let m = d.join("huge.npy");
    std::fs::write(&m, bytes).unwrap();
    let err = fails(&polnlos(&[
        "reconstruct",
        scene("brewster-crossed-3x3").to_str().unwrap(),
        "--measurement",
        m.to_str().unwrap(),
        "--out",
        d.join("o").to_str().unwrap(),
    ]));
    assert!(err.contains("huge.npy") && err.contains("shape"), "{err}");
    // Values that used to pass validation: all-NaN T, a meaningless angle, a
    // block listed twice (the daemon could never reconstruct that scene).
    for (from, to, key) in [
        ("ior = 1.5", "ior = 1e308", "wall.ior"),
        (
            "polarizer_deg = [0.0]",
            "polarizer_deg = [1e308]",
            "polarizer_deg",
        ),
        (
            "polarizer_deg = [0.0]",
            "polarizer_deg = [0, 0, 360]",
            "same polarizer setting",
        ),
    ] {
        let p = edited_scene(d, "bad.toml", &[(from, to)]);
        let err = fails(&polnlos(&["cond", p.to_str().unwrap()]));
        assert!(err.contains(key), "{to}: {err}");
    }
    // --spot is one argument U,V, as its help and the README say.
    let err = usage(&polnlos(&[
        "transport",
        "brewster-crossed-3x3",
        "--active",
        "--spot",
        "0.05",
        "--out",
        d.join("a.npy").to_str().unwrap(),
    ]));
    assert!(err.contains("is not U,V"), "{err}");
    // A 4096^2 wall is refused before it allocates, with what to reduce.
    let p = edited_scene(
        d,
        "huge-wall.toml",
        &[("grid = [32, 32]", "grid = [4096, 4096]")],
    );
    let err = fails(&polnlos(&["cond", p.to_str().unwrap()]));
    assert!(err.contains("reduce wall.grid to at most"), "{err}");
}

#[test]
#[cfg(feature = "report")]
fn bench_quick_writes_its_reports() {
    let dir = tempfile::tempdir().unwrap();
    ok(&polnlos(&[
        "bench",
        "--quick",
        "--out",
        dir.path().to_str().unwrap(),
    ]));
    for f in [
        "bench.json",
        "bench.md",
        "conditioning.png",
        "conditioning.svg",
        "roughness.png",
        "roughness.svg",
        "speed-accuracy-S.png",
        "speed-accuracy-S.svg",
        "sampling.png",
        "sampling.svg",
        "active.png",
        "active.svg",
        "lambda.png",
        "lambda.svg",
        "rendered.png",
        "rendered.svg",
    ] {
        assert!(dir.path().join(f).metadata().unwrap().len() > 100, "{f}");
    }
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("bench.json")).unwrap()).unwrap();
    assert_eq!(v["conditioning"].as_array().unwrap().len(), 8);
    // The Mitsuba renders (cases read from tests/data/rendered): agreement at
    // the noise under revision 2, far from it under revision 1; the Fig. 9
    // post-processing question answered at both noises.
    let rendered = &v["rendered"];
    assert!(rendered["skipped"].is_null(), "{rendered}");
    let rows = rendered["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 2, "{rendered}");
    for r in rows {
        assert!(r["agreement"]["ratio"].as_f64().unwrap() < 1.5, "{r}");
    }
    let crossed = rows.iter().find(|r| r["case"] == "crossed").unwrap();
    assert!(crossed["agreement_revision_1"]["ratio"].as_f64().unwrap() > 10.0);
    assert_eq!(rendered["post_processing"].as_array().unwrap().len(), 2);
    assert_eq!(v["roughness"].as_array().unwrap().len(), 42);
    let crossed = v["conditioning"]
        .as_array()
        .unwrap()
        .iter()
        .find(|r| r["scene"] == "brewster-crossed-3x3")
        .unwrap();
    assert!((crossed["kappa"].as_f64().unwrap() / 113.5036206092875 - 1.0).abs() < 1e-6);
    let md = std::fs::read_to_string(dir.path().join("bench.md")).unwrap();
    assert!(
        md.contains("| 3x3 | no | 2.028e2 | 1.833e2 | 1.135e2 | 7.980e1 | holds |"),
        "{md}"
    );
    assert!(std::fs::read_to_string(dir.path().join("roughness.svg"))
        .unwrap()
        .starts_with("<svg"));
    let png = image::read_gray(&dir.path().join("conditioning.png")).unwrap();
    assert_eq!((png.width, png.height), (900, 560));

    // The automatic λ on the quick plan's 3 cases (3x3, 1e4 e-): the
    // residual's sigma is the camera model's, the gap is best minus
    // automatic, and 8 of the 9 components count as resolved.
    let lambda = v["lambda"].as_array().unwrap();
    assert_eq!(lambda.len(), 3);
    for r in lambda {
        let f = |k: &str| r[k].as_f64().unwrap();
        assert!((0.85..1.15).contains(&f("noise_ratio")), "{r}");
        assert!(
            (f("best_psnr") - f("auto_psnr") - f("gap")).abs() < 1e-9,
            "{r}"
        );
        assert!(f("gap") >= 0.0 && r["resolved"] == 8, "{r}");
    }
    assert!(md.contains("## Automatic λ against the best λ"), "{md}");

    // Stability: the measurement that is mostly noise says so.
    let dim = v["stability"]
        .as_array()
        .unwrap()
        .iter()
        .find(|r| r["case"] == "1e2 photons at full scale")
        .unwrap();
    assert!(dim["warnings"].to_string().contains("mean SNR"), "{dim}");

    // Speed against accuracy: 2 exposures x (lsq, tikhonov, 3 ADMM + 3 FISTA
    // budgets, 3 tolerances, the unpolarized reference).
    let speed = v["speed"].as_array().unwrap();
    assert_eq!(speed.len(), 2 * 12);
    let get = |exposure: &str, solver: &str, budget: &str| {
        speed
            .iter()
            .find(|r| r["exposure"] == exposure && r["solver"] == solver && r["budget"] == budget)
            .unwrap_or_else(|| panic!("{exposure} {solver} {budget} missing"))
    };
    for exposure in ["equal exposure", "equal photon budget"] {
        let lsq = get(exposure, "lsq", "-")["psnr_db"].as_f64().unwrap();
        let admm = get(exposure, "admm-tv", "200")["psnr_db"].as_f64().unwrap();
        let fista = get(exposure, "fista-tv", "200")["psnr_db"]
            .as_f64()
            .unwrap();
        assert!(admm > lsq + 5.0, "{exposure}: ADMM {admm} vs LSQ {lsq}");
        assert!(
            (admm - fista).abs() < 1.0,
            "{exposure}: ADMM {admm} vs FISTA {fista}"
        );
        assert!(speed
            .iter()
            .any(|r| r["exposure"] == exposure && r["pareto"] == true));
    }
    let png = image::read_gray(&dir.path().join("speed-accuracy-S.png")).unwrap();
    assert_eq!((png.width, png.height), (1800, 1120));
    assert!(md.contains("## Speed against accuracy"));

    // Transport accuracy: 2 cases x (6 uniform + 5 adaptive); error falls with m.
    let sampling = v["sampling"].as_array().unwrap();
    assert_eq!(sampling.len(), 22);
    for case in ["glossy wall (alpha 0.05)", "occluder (alpha 0.3)"] {
        let err = |method: &str, setting: f64| {
            sampling
                .iter()
                .find(|r| r["case"] == case && r["method"] == method && r["setting"] == setting)
                .unwrap()["error"]
                .as_f64()
                .unwrap()
        };
        assert!(err("uniform", 4.0) < 0.5 * err("uniform", 1.0), "{case}");
        assert!(err("adaptive", 1e-2) < 0.5 * err("uniform", 1.0), "{case}");
    }

    // Active NLOS: 2 configs x (2 grids + 7 roughness values).
    let act = v["active"].as_array().unwrap();
    assert_eq!(act.len(), 18);
    let k = |config: &str, field: &str| {
        act.iter()
            .find(|r| r["sweep"] == "resolution" && r["config"] == config && r["grid"] == 3)
            .unwrap()[field]
            .as_f64()
            .unwrap()
    };
    assert!(k("crossed", "kappa_active") < k("nopol", "kappa_active"));
    assert!(k("nopol", "kappa_active") < k("nopol", "kappa_passive"));

    // The NumPy peer (CI installs python3-numpy): same T, same recovery.
    let peer = &v["peer"];
    assert!(
        peer["skipped"].is_null(),
        "peer skipped: {}",
        peer["skipped"]
    );
    assert!(peer["t_difference"].as_f64().unwrap() < 1e-9, "{peer}");
    assert!(
        peer["recovery_difference"].as_f64().unwrap() < 1e-6,
        "{peer}"
    );
    assert!(md.contains("## Against a NumPy peer"));
}

#[test]
fn grid_recommends_a_grid_and_more_light_allows_a_finer_one() {
    let s = scene("occluder-crossed");
    let run = |photons: &str| -> serde_json::Value {
        serde_json::from_str(&ok(&polnlos(&[
            "grid",
            s.to_str().unwrap(),
            "--photons",
            photons,
            "--grids",
            "2,3,4,6,8",
            "--json",
        ])))
        .unwrap()
    };
    let dim = run("1000");
    let bright = run("10000000");
    assert_eq!(dim["rows"].as_array().unwrap().len(), 5);
    let rec = |v: &serde_json::Value| v["recommended"].as_u64().unwrap_or(0);
    assert!(
        rec(&bright) > rec(&dim),
        "dim {} bright {}",
        dim["recommended"],
        bright["recommended"]
    );
    // `plan`, its name before the eighteenth session, still works.
    let text = ok(&polnlos(&["plan", s.to_str().unwrap(), "--grids", "3,8"]));
    assert!(
        text.contains("recommended") || text.contains("no candidate"),
        "{text}"
    );
}

#[test]
fn a_pattern_on_a_scene_grid_is_the_daemons_truth_for_that_scene() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("letter.png");
    let said = ok(&polnlos(&[
        "pattern",
        "letter",
        "--scene",
        "brewster-crossed",
        "--out",
        out.to_str().unwrap(),
    ]));
    let scene = polnlos::scene::Scene::builtin("brewster-crossed")
        .expect("a built-in scene")
        .unwrap();
    let grid = scene.hidden().plane.grid;
    assert!(
        said.contains(&format!("{} x {} pixels", grid.nu, grid.nv)),
        "{said}"
    );
    let png = image::read_gray(&out).unwrap();
    // The daemon's truth for "truth": "letter" on this scene (Daemon::truth_png).
    let expect = grid.to_top_first(&Pattern::Letter.render(grid), 1);
    assert_eq!(png.data.len(), expect.len());
    assert!(png
        .data
        .iter()
        .zip(&expect)
        .all(|(a, b)| (a - b).abs() < 1e-4));
    // A size and a scene are two answers to one question.
    usage(&polnlos(&[
        "pattern",
        "letter",
        "--scene",
        "brewster-crossed",
        "--size",
        "64",
        "--out",
        "x.png",
    ]));
}

#[test]
fn exit_status_says_whose_the_error_is() {
    let d = tempfile::tempdir().unwrap();
    // 2: the command line (clap's own, and ranges polnlos checks itself).
    usage(&polnlos(&["pattern", "circle"]));
    usage(&polnlos(&[
        "pattern", "disk", "--size", "0", "--out", "x.png",
    ]));
    // 3: a file the user named.
    fails(&polnlos(&[
        "cond",
        d.path().join("none.toml").to_str().unwrap(),
    ]));
    // 1: the input was fine, the work failed (here: the result cannot be written).
    let blocked = d.path().join("file");
    std::fs::write(&blocked, b"x").unwrap();
    let err = fails_with(
        1,
        &polnlos(&[
            "pattern",
            "disk",
            "--out",
            blocked.join("disk.png").to_str().unwrap(),
        ]),
    );
    assert!(err.contains("disk.png"), "{err}");
    let help = ok(&polnlos(&["--help"]));
    assert!(
        help.contains("Exit status: 0 done; 1 the work failed"),
        "{help}"
    );
}

#[test]
fn calibrate_geometry_recovers_a_pose_from_an_image_of_the_target() {
    use polnlos::calibrate::geometry::{render, Target};
    let d = tempfile::tempdir().unwrap();
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let target_file = root.join("config/targets/dots-5x5.toml");
    let target = Target::from_toml_str(&std::fs::read_to_string(&target_file).unwrap()).unwrap();
    let shipped = Scene::builtin("brewster-crossed").unwrap().unwrap();
    let h = shipped.pose("A").unwrap().homography.unwrap();
    let frame = render(&target, &h, 512, 512);
    let px: Vec<u16> = frame
        .pixels
        .iter()
        .map(|&v| (v * 50000.0 + 4000.0) as u16)
        .collect();
    let img = d.path().join("target-A.png");
    image::write_png16(&img, 512, 512, &px).unwrap();
    let out = d.path().join("calibrated.toml");
    let calibrate = |image: &std::path::Path, target: &str| {
        polnlos(&[
            "calibrate",
            "geometry",
            image.to_str().unwrap(),
            "--target",
            target,
            "--scene",
            "brewster-crossed",
            "--pose",
            "A",
            "--out",
            out.to_str().unwrap(),
        ])
    };
    let o = calibrate(&img, target_file.to_str().unwrap());
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(o.status.success(), "{err}");
    println!("{err}");
    assert!(err.contains("26 dots, reprojection error RMS"), "{err}");
    let s = Scene::from_toml_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    let fitted = s.pose("A").unwrap().homography.unwrap();
    let worst = polnlos::calibrate::geometry::max_distance(&fitted, &h, &target.dots);
    assert!(worst < 0.3, "{worst} px from the shipped homography");
    // The daemon's mean.tiff (32-bit float, DN) calibrates the same way,
    // with the built-in target named as scenes are.
    let tiff_path = d.path().join("mean.tiff");
    {
        let f = std::fs::File::create(&tiff_path).unwrap();
        let mut enc = tiff::encoder::TiffEncoder::new(std::io::BufWriter::new(f)).unwrap();
        let dn: Vec<f32> = frame.pixels.iter().map(|&v| v * 50000.0 + 4000.0).collect();
        enc.write_image::<tiff::encoder::colortype::Gray32Float>(512, 512, &dn)
            .unwrap();
    }
    let o = calibrate(&tiff_path, "dots-5x5");
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(o.status.success(), "mean.tiff: {err}");
    let s = Scene::from_toml_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    let from_tiff = s.pose("A").unwrap().homography.unwrap();
    let worst = polnlos::calibrate::geometry::max_distance(&from_tiff, &h, &target.dots);
    assert!(
        worst < 0.3,
        "{worst} px from the shipped homography (mean.tiff)"
    );
    // An image without the whole target is a clear input error (status 3).
    let blank = d.path().join("blank.png");
    image::write_png16(&blank, 64, 64, &vec![100u16; 64 * 64]).unwrap();
    let err = fails(&polnlos(&[
        "calibrate",
        "geometry",
        blank.to_str().unwrap(),
        "--target",
        target_file.to_str().unwrap(),
        "--scene",
        "brewster-crossed",
        "--pose",
        "A",
    ]));
    assert!(
        err.contains("found 0 dots in the image but the target has 26"),
        "{err}"
    );
}

#[test]
fn calibrate_wall_fits_a_point_source_measurement_with_uncertainties() {
    use polnlos::calibrate::wall::{predict, PointSource, WallParams};
    let d = tempfile::tempdir().unwrap();
    let scene = Scene::builtin("brewster-rotating").unwrap().unwrap();
    let truth = WallParams {
        alpha: 0.25,
        ior: 1.6,
        kd: 0.04,
        gain: 3.0,
    };
    // The measurement of the source at (u, v), written as .npy.
    let measured = |file: &str, u: f64, v: f64| {
        let i = predict(&scene, &PointSource { u, v }, &truth, MemoryBudget::DEFAULT).unwrap();
        let m = d.path().join(file);
        npy::write_f64(&m, &[i.len()], &i).unwrap();
        m.to_str().unwrap().to_string()
    };
    // `calibrate wall` with --measurement/--source pairs.
    let wall = |pairs: &[(&str, &str)]| {
        let mut args = vec![
            "calibrate".to_string(),
            "wall".into(),
            "brewster-rotating".into(),
        ];
        for (m, source) in pairs {
            args.extend(["--measurement".to_string(), m.to_string()]);
            args.push(format!("--source={source}"));
        }
        polnlos(&args.iter().map(String::as_str).collect::<Vec<_>>())
    };
    let param = |f: &serde_json::Value, k: &str| f["params"][k].as_f64().unwrap();
    let m = measured("source.npy", 0.03, -0.02);
    let out = ok(&wall(&[(&m, "0.03,-0.02")]));
    println!("{out}");
    let f: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert!((param(&f, "alpha") - 0.25).abs() < 0.01, "{f}");
    assert!((param(&f, "ior") - 1.6).abs() < 0.02, "{f}");
    assert!((param(&f, "kd") - 0.04).abs() < 0.005, "{f}");
    assert!((param(&f, "gain") / 3.0 - 1.0).abs() < 0.02, "{f}");
    assert!(f["sigma"]["alpha"].as_f64().unwrap().is_finite(), "{f}");
    // The wrong source position: refused, exit status 3.
    let err = fails(&wall(&[(&m, "-0.06,0.06")]));
    assert!(err.contains("do not match the capture"), "{err}");
    // Two positions of the same source, fitted together (one gain).
    let m2 = measured("source-2.npy", -0.06, 0.05);
    let out = ok(&wall(&[(&m, "0.03,-0.02"), (&m2, "-0.06,0.05")]));
    let f: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert!((param(&f, "ior") - 1.6).abs() < 0.02, "{f}");
    assert!((param(&f, "gain") / 3.0 - 1.0).abs() < 0.02, "{f}");
    assert_eq!(
        f["source_residuals"].as_array().map(Vec::len),
        Some(2),
        "{f}"
    );
    // Positions and measurements must pair up: a usage error (status 2).
    let err = usage(&polnlos(&[
        "calibrate",
        "wall",
        "brewster-rotating",
        "--measurement",
        &m,
        "--measurement",
        &m2,
        "--source",
        "0.03,-0.02",
    ]));
    assert!(err.contains("2 --measurement but 1 --source"), "{err}");
}

/// Writes `pages` constant 16-bit pages of `size` x `size` pixels.
fn write_tiff_pages(path: &std::path::Path, size: u32, pages: &[u16]) {
    use tiff::encoder::{colortype, TiffEncoder};
    let mut f = std::fs::File::create(path).unwrap();
    let mut enc = TiffEncoder::new(&mut f).unwrap();
    for &v in pages {
        let px = vec![v; (size * size) as usize];
        enc.write_image::<colortype::Gray16>(size, size, &px)
            .unwrap();
    }
}

#[test]
fn measure_turns_tiff_frames_into_the_measurement_in_block_order() {
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n).to_str().unwrap().to_string();
    let run = |args: &[String]| {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        polnlos(&args)
    };
    let strings = |a: &[&str]| a.iter().map(|s| s.to_string()).collect::<Vec<String>>();
    // Pose B sees 1100 +- 10 DN, pose C 600 DN; both over a 100 DN dark.
    write_tiff_pages(
        dir.path().join("B.tiff").as_path(),
        512,
        &[1090, 1110, 1090, 1110],
    );
    write_tiff_pages(dir.path().join("C.tiff").as_path(), 512, &[600, 600]);
    write_tiff_pages(dir.path().join("dark.tiff").as_path(), 512, &[100, 100]);
    let s = scene("brewster-multi-3x3").to_str().unwrap().to_string();
    let out = p("m/i.npy");
    // Blocks given C first: they are stacked B, C as the scene orders them.
    let mut args = strings(&[
        "measure",
        &s,
        "--frames",
        &p("C.tiff"),
        "--frames",
        &p("B.tiff"),
    ]);
    args.extend(strings(&[
        "--dark",
        &p("dark.tiff"),
        "--pose",
        "C",
        "--pose",
        "B",
    ]));
    args.extend(strings(&[
        "--angle",
        "0",
        "--exposure-us",
        "1000",
        "--raw",
        "--out",
        &out,
    ]));
    let stdout = ok(&run(&args));
    assert!(stdout.contains("2 blocks B-pol0 C-pol0"), "{stdout}");
    let i = npy::read(std::path::Path::new(&out)).unwrap().data;
    let n = i.len() / 2;
    let unit = 1.0 / 65535.0 / 1000.0;
    assert!(
        i[..n]
            .iter()
            .all(|v| (v - 1000.0 * unit).abs() < 1e-9 * unit),
        "{:?}",
        &i[..3]
    );
    assert!(i[n..]
        .iter()
        .all(|v| (v - 500.0 * unit).abs() < 1e-9 * unit));
    // Variance of B's 4-frame mean (f32 in the frame): sample variance 400/3 DN², over 4 frames,
    // per pixel; C's frames do not vary: only the digitizer's rounding floor, 1/12 DN². An element
    // averages its pixels with weights w_p: its variance is the pixels' times sum w_p²
    // (MODEL.md revision 3; the dark's two frames are equal and add none).
    let var = npy::read(std::path::Path::new(&p("m/i.variance.npy")))
        .unwrap()
        .data;
    let multi = Scene::load(std::path::Path::new(&s)).unwrap();
    let w2 = |pose: usize| {
        let h = multi.poses()[pose].homography.unwrap();
        let g = polnlos::scene::FrameGeometry::plain(512, 512);
        let map = polnlos::scene::PixelMap::frame(&h, &multi.wall().plane, g, "p").unwrap();
        map.weights()[map.range(0)]
            .iter()
            .map(|w| w * w)
            .sum::<f64>()
    };
    assert!(w2(0) < 0.05, "element 0 of pose B has dozens of pixels");
    assert!(
        (var[0] / unit / unit - 400.0 / 3.0 / 4.0 * w2(0)).abs() < 1e-5,
        "{}",
        var[0] / unit / unit
    );
    assert!((var[n] / unit / unit - w2(1) / 12.0).abs() < 1e-9);
    // With a gain: units of T l, the raw values divided by it.
    let mut gained = args.clone();
    gained.retain(|a| a != "--raw");
    gained.extend(strings(&["--gain", "0.5"]));
    ok(&run(&gained));
    let g = npy::read(std::path::Path::new(&out)).unwrap().data;
    assert!((g[0] - 2.0 * i[0]).abs() < 1e-15);

    // What a user gets wrong is named: the command line (exit status 2)...
    let mut three_poses = args.clone();
    three_poses.extend(strings(&["--pose", "C"]));
    let e = usage(&run(&three_poses));
    assert!(e.contains("3 values of --pose for 2 --frames"), "{e}");
    // ...and the frames (exit status 3).
    let only_b = |angle: &str, frames: &str| {
        let mut a = strings(&[
            "measure", &s, "--frames", frames, "--pose", "B", "--angle", angle,
        ]);
        a.extend(strings(&["--exposure-us", "1000", "--raw", "--out", &out]));
        a
    };
    let e = fails(&run(&only_b("0", &p("B.tiff"))));
    assert!(e.contains("no capture for block C-pol0"), "{e}");
    // Without --dark it was told so, in the words the daemon uses, with the flag to give.
    assert!(
        e.contains("B.tiff has no dark subtraction") && e.contains("with --dark"),
        "{e}"
    );
    let mut stray = strings(&[
        "measure",
        &s,
        "--frames",
        &p("B.tiff"),
        "--frames",
        &p("C.tiff"),
    ]);
    stray.extend(strings(&[
        "--frames",
        &p("C.tiff"),
        "--pose",
        "B",
        "--pose",
        "C",
        "--pose",
        "C",
    ]));
    stray.extend(strings(&["--angle", "0", "--angle", "0", "--angle", "45"]));
    stray.extend(strings(&["--exposure-us", "1000", "--raw", "--out", &out]));
    let e = fails(&run(&stray));
    assert!(
        e.contains("C.tiff was taken at C-pol45, which is not a block"),
        "{e}"
    );
    write_tiff_pages(dir.path().join("small.tiff").as_path(), 64, &[5]);
    let mut small = only_b("0", &p("small.tiff"));
    small.extend(strings(&["--dark", &p("dark.tiff")]));
    let e = fails(&run(&small));
    assert!(
        e.contains("the dark frame is 512x512 but the frames are 64x64"),
        "{e}"
    );
}

#[test]
fn frames_that_cut_the_wall_or_simulated_frames_of_a_scene_are_measured_or_refused_plainly() {
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n).to_str().unwrap().to_string();
    let s = scene("brewster-crossed-3x3").to_str().unwrap().to_string();
    // A 300x300 frame holds only part of the wall's image: the error names the
    // pose and an element, and nothing is written.
    write_tiff_pages(dir.path().join("small.tiff").as_path(), 300, &[100, 110]);
    let args = [
        "measure",
        &s,
        "--frames",
        &p("small.tiff"),
        "--pose",
        "A",
        "--angle",
        "0",
        "--exposure-us",
        "1000",
        "--raw",
        "--out",
        &p("i.npy"),
    ];
    let e = fails(&polnlos(&args));
    assert!(
        e.contains("pose \"A\": wall element") && e.contains("partly outside the frame"),
        "{e}"
    );
    assert!(!dir.path().join("i.npy").exists());
    // Frames simulated pixel by pixel (with a dark level and its dark frames)
    // measure back to the wall image: the letter's brightest element is found.
    let truth = p("letter.png");
    ok(&polnlos(&[
        "pattern", "letter", "--size", "32", "--out", &truth,
    ]));
    ok(&polnlos(&[
        "simulate",
        &s,
        "--truth",
        &truth,
        "--out",
        &p("sim"),
        "--photons",
        "20000",
        "--frames",
        "--frame-count",
        "3",
        "--dark-level",
        "64",
        "--seed",
        "4",
    ]));
    let sim: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("sim/simulate.json")).unwrap(),
    )
    .unwrap();
    let gain = sim["frame_gain"].as_f64().unwrap();
    assert!((gain * sim["unpolarized_peak"].as_f64().unwrap() - 1.0).abs() < 1e-12);
    let frames =
        polnlos::files::frames::read_frames(&dir.path().join("sim/frames-A-pol0.tiff")).unwrap();
    assert_eq!((frames.stack.count, frames.full_scale()), (3, Some(4095.0)));
    let out = ok(&polnlos(&[
        "measure",
        &s,
        "--frames",
        &p("sim/frames-A-pol0.tiff"),
        "--dark",
        &p("sim/dark-A-pol0.tiff"),
        "--pose",
        "A",
        "--angle",
        "0",
        "--exposure-us",
        "1",
        "--raw",
        "--out",
        &p("sim/i.npy"),
    ]));
    assert!(
        out.contains("1 blocks A-pol0") || out.contains("A-pol0"),
        "{out}"
    );
    let i = npy::read(&dir.path().join("sim/i.npy")).unwrap().data;
    let var = npy::read(&dir.path().join("sim/i.variance.npy"))
        .unwrap()
        .data;
    assert_eq!((i.len(), var.len()), (1024, 1024));
    // The dark level is gone: the darkest element sits near the simulated
    // wall's darkest (its own light, a few DN), not 64 DN above it.
    let min = i.iter().copied().fold(f64::INFINITY, f64::min) * 4095.0;
    let wall = npy::read(&dir.path().join("sim/measurement.npy"))
        .unwrap()
        .data;
    let wall_min = wall.iter().copied().fold(f64::INFINITY, f64::min) * gain * 4095.0;
    assert!(
        (min - wall_min).abs() < 10.0,
        "darkest element {min} DN against the simulated wall's {wall_min} DN"
    );
    assert!(var.iter().all(|v| *v > 0.0));
}

#[test]
fn a_mosaic_frame_measures_to_its_four_blocks_in_angle_order() {
    use tiff::encoder::{colortype, TiffEncoder};
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n).to_str().unwrap().to_string();
    // Polarsens (row, col) mod 2: (0,0) 90°, (0,1) 45°, (1,0) 135°, (1,1) 0°.
    let level = |x: usize, y: usize| match (y % 2, x % 2) {
        (0, 0) => 900u16,
        (0, _) => 450,
        (1, 0) => 1350,
        _ => 100,
    };
    let px: Vec<u16> = (0..512 * 512).map(|k| level(k % 512, k / 512)).collect();
    let mut f = std::fs::File::create(p("mosaic.tiff")).unwrap();
    TiffEncoder::new(&mut f)
        .unwrap()
        .write_image::<colortype::Gray16>(512, 512, &px)
        .unwrap();
    let out = p("i.npy");
    let s = scene("brewster-rotating-3x3").to_str().unwrap().to_string();
    let text = std::fs::read_to_string(&s).unwrap().replace(
        "polarizer_deg = [0.0, 45.0, 90.0, 135.0]",
        "analyzer = \"mosaic\"\nsensor_deg = 0.0",
    );
    let mosaic = p("mosaic.toml");
    std::fs::write(&mosaic, text).unwrap();
    let args = |angle: &str, scene: &str| {
        polnlos(&[
            "measure",
            scene,
            "--frames",
            &p("mosaic.tiff"),
            "--pose",
            "A",
            "--angle",
            angle,
            "--exposure-us",
            "1000",
            "--raw",
            "--out",
            &out,
        ])
    };
    let stdout = ok(&args("mosaic", &mosaic));
    assert!(
        stdout.contains("4 blocks A-mosaic0 A-mosaic45 A-mosaic90 A-mosaic135"),
        "{stdout}"
    );
    let i = npy::read(std::path::Path::new(&out)).unwrap().data;
    let n = i.len() / 4;
    let unit = 1.0 / 65535.0 / 1000.0;
    for (k, want) in [100.0, 450.0, 900.0, 1350.0].into_iter().enumerate() {
        assert!(
            i[k * n..(k + 1) * n]
                .iter()
                .all(|v| (v - want * unit).abs() < 1e-9 * want * unit),
            "block {k}: {:?}",
            &i[k * n..k * n + 3]
        );
    }
    // A mosaic frame on a scene whose pose has a sheet names the blocks it cannot serve.
    let e = fails(&args("mosaic", &s));
    assert!(e.contains("A-mosaic0, which is not a block"), "{e}");
    let e = usage(&args("mosaik", &mosaic));
    assert!(e.contains("`none` or `mosaic`"), "{e}");
}

#[test]
fn a_bayer_frame_measures_to_red_green_and_blue_per_row() {
    use tiff::encoder::{colortype, TiffEncoder};
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n).to_str().unwrap().to_string();
    // GRBG: G R on even rows, B G on odd ones; two frames each, for a variance.
    let level = |x: usize, y: usize, k: u16| match (y % 2, x % 2) {
        (0, 1) => 1000 + k,
        (1, 0) => 3000 + k,
        _ => 2000 + k,
    };
    {
        let mut f = std::fs::File::create(p("raw.tiff")).unwrap();
        let mut enc = TiffEncoder::new(&mut f).unwrap();
        for k in 0..2u16 {
            let px: Vec<u16> = (0..512 * 512)
                .map(|q| level(q % 512, q / 512, 2 * k))
                .collect();
            enc.write_image::<colortype::Gray16>(512, 512, &px).unwrap();
        }
    }
    let out = p("i.npy");
    let s = scene("brewster-crossed").to_str().unwrap().to_string();
    let args = |bayer: &str| {
        polnlos(&[
            "measure",
            &s,
            "--frames",
            &p("raw.tiff"),
            "--pose",
            "A",
            "--angle",
            "0",
            "--exposure-us",
            "1000",
            "--raw",
            "--bayer",
            bayer,
            "--out",
            &out,
        ])
    };
    let stdout = ok(&args("GR"));
    assert!(
        stdout.contains("1024 rows x 3 colours, red green blue"),
        "{stdout}"
    );
    let m = npy::read(std::path::Path::new(&out)).unwrap();
    assert_eq!(m.shape, vec![1024, 3]);
    let unit = 1.0 / 65535.0 / 1000.0;
    for (c, want) in [1001.0, 2001.0, 3001.0].into_iter().enumerate() {
        assert!(
            m.data
                .iter()
                .skip(c)
                .step_by(3)
                .all(|v| (v - want * unit).abs() < 1e-9),
            "colour {c}: {:?}",
            &m.data[..6]
        );
    }
    let v = npy::read(&dir.path().join("i.variance.npy")).unwrap();
    assert_eq!(v.shape, vec![1024, 3]);
    // The wrong pattern reads green where red is.
    ok(&args("RG"));
    let m = npy::read(std::path::Path::new(&out)).unwrap();
    assert!(
        (m.data[0] - 2001.0 * unit).abs() < 1e-9,
        "{:?}",
        &m.data[..3]
    );
    let e = usage(&args("RGB"));
    assert!(e.contains("give RG, GR, GB or BG"), "{e}");
    // The same colours demosaiced by the camera, as an RGB TIFF.
    {
        let mut f = std::fs::File::create(p("rgb.tiff")).unwrap();
        let mut enc = TiffEncoder::new(&mut f).unwrap();
        for k in 0..2u16 {
            let px: Vec<u16> = (0..512 * 512)
                .flat_map(|_| [1000 + 2 * k, 2000 + 2 * k, 3000 + 2 * k])
                .collect();
            enc.write_image::<colortype::RGB16>(512, 512, &px).unwrap();
        }
    }
    let rgb_tiff = p("rgb.tiff");
    let rgb = |extra: &[&str]| {
        let mut args = vec![
            "measure",
            &s,
            "--frames",
            &rgb_tiff,
            "--pose",
            "A",
            "--angle",
            "0",
            "--exposure-us",
            "1000",
            "--raw",
            "--out",
            &out,
        ];
        args.extend_from_slice(extra);
        polnlos(&args)
    };
    let stdout = ok(&rgb(&[]));
    assert!(stdout.contains("1024 rows x 3 colours"), "{stdout}");
    let m = npy::read(std::path::Path::new(&out)).unwrap();
    assert_eq!(m.shape, vec![1024, 3]);
    for (c, want) in [1001.0, 2001.0, 3001.0].into_iter().enumerate() {
        assert!(
            m.data
                .iter()
                .skip(c)
                .step_by(3)
                .all(|v| (v - want * unit).abs() < 1e-9),
            "RGB colour {c}: {:?}",
            &m.data[..6]
        );
    }
    let e = usage(&rgb(&["--bayer", "RG"]));
    assert!(e.contains("already demosaiced"), "{e}");
    // The plain reconstruction refuses the colours, naming --photo.
    let e = usage(&polnlos(&[
        "reconstruct",
        &s,
        "--measurement",
        &out,
        "--out",
        &p("rec"),
    ]));
    assert!(e.contains("reconstruct --photo"), "{e}");
}

#[test]
fn saturated_pixels_leave_their_elements_out_of_measure_and_reconstruct() {
    use tiff::encoder::{colortype, TiffEncoder};
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n).to_str().unwrap().to_string();
    let s = scene("brewster-crossed").to_str().unwrap().to_string();
    // Two flat 16-bit frames, four pixels at full scale in the second.
    let mut f = std::fs::File::create(p("frames.tiff")).unwrap();
    {
        let mut enc = TiffEncoder::new(&mut f).unwrap();
        for k in 0..2u16 {
            let mut px: Vec<u16> = (0..512 * 512).map(|q| 2000 + (q % 7) as u16 + k).collect();
            if k == 1 {
                for (x, y) in [(256, 256), (257, 256), (256, 257), (300, 200)] {
                    px[y * 512 + x] = 65535;
                }
            }
            enc.write_image::<colortype::Gray16>(512, 512, &px).unwrap();
        }
    }
    let i = p("i.npy");
    let run = polnlos(&[
        "measure",
        &s,
        "--frames",
        &p("frames.tiff"),
        "--pose",
        "A",
        "--angle",
        "0",
        "--exposure-us",
        "1000",
        "--gain",
        "1e-3",
        "--out",
        &i,
    ]);
    let stderr = String::from_utf8_lossy(&run.stderr).into_owned();
    ok(&run);
    let m = npy::read(std::path::Path::new(&i)).unwrap();
    let nan = m.data.iter().filter(|v| v.is_nan()).count();
    // The four pixels fall in one or two wall elements.
    assert!((1..=2).contains(&nan), "{nan}");
    assert!(
        stderr.contains(&format!("{nan} of 1024 wall elements were not measured")),
        "{stderr}"
    );
    let v = npy::read(&dir.path().join("i.variance.npy")).unwrap();
    assert_eq!(v.data.iter().filter(|v| v.is_nan()).count(), nan);
    // reconstruct leaves them out and says so.
    let run = polnlos(&[
        "reconstruct",
        &s,
        "--measurement",
        &i,
        "--variance",
        &p("i.variance.npy"),
        "--out",
        &p("rec"),
    ]);
    let stderr = String::from_utf8_lossy(&run.stderr).into_owned();
    ok(&run);
    assert!(
        stderr.contains(&format!("{nan} of 1024 wall elements were not measured")),
        "{stderr}"
    );
    let rec = npy::read(&dir.path().join("rec/recovered.npy")).unwrap();
    assert!(rec.data.iter().all(|v| v.is_finite()));
}

/// `polnlos reconstruct` of the chair photo's scene with `--photo`.
fn reconstruct_photo(measurement: &Path, out: &Path, truth: Option<&Path>, cache: &Path) -> Output {
    crate::priority::background();
    photo_command(measurement, out, truth, cache)
        .output()
        .expect("run polnlos")
}

/// `polnlos reconstruct --photo` of the chair scene on `measurement`.
fn photo_command(measurement: &Path, out: &Path, truth: Option<&Path>, cache: &Path) -> Command {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut c = Command::new(env!("CARGO_BIN_EXE_polnlos"));
    c.arg("reconstruct")
        .arg(root.join("config/photos/saunders-chair.toml"))
        .arg("--photo")
        .arg("--measurement")
        .arg(measurement)
        .arg("--out")
        .arg(out)
        .env("POLNLOS_CACHE", cache);
    if let Some(t) = truth {
        c.arg("--truth").arg(t);
    }
    c
}

/// The CLI's `reconstruct --photo` of the chair, with its truth, run once
/// for the whole suite: this test and the daemon's import test
/// (`daemon::photos`) both read it, so the 3-channel fit with both shadow
/// models is not paid twice. Its folder and `T` cache sit in a fixed place
/// under `target/tmp`, cleared when the run starts.
pub(crate) struct ChairPhotoRun {
    /// `--out`: recovered.npy, report.json, recovered.png.
    pub out: PathBuf,
    /// `$POLNLOS_CACHE` the run stored its `T` in.
    pub cache: PathBuf,
    /// What the CLI printed.
    pub output: Output,
}

/// The shared chair run ([`ChairPhotoRun`]), made by the first caller.
pub(crate) fn chair_photo_run() -> &'static ChairPhotoRun {
    static RUN: std::sync::OnceLock<ChairPhotoRun> = std::sync::OnceLock::new();
    RUN.get_or_init(|| {
        let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
        let data = root.join("tests/data/saunders-chair");
        let base = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("chair-photo");
        let _ = std::fs::remove_dir_all(&base);
        let (out, cache) = (base.join("out"), base.join("cache"));
        std::fs::create_dir_all(&cache).unwrap();
        // Run at the caller's priority: the daemon test that may start it
        // holds the Aravis lock and must not drop to the idle class.
        let output = photo_command(
            &data.join("measurement.npy"),
            &out,
            Some(&data.join("truth_rgb.npy")),
            &cache,
        )
        .output()
        .expect("run polnlos");
        ChairPhotoRun { out, cache, output }
    })
}

/// Saunders et al.'s chair photo (tests/data/saunders-chair, imported by
/// validation/saunders/convert.py): gain, background and λ from the photo
/// alone, three colour channels through one T, against the monitor's image.
#[test]
fn a_real_colour_photo_reconstructs_with_gain_background_and_lambda_from_itself() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let data = root.join("tests/data/saunders-chair");
    // T (132 MB) is kept in the run's own cache between the calls.
    let run = chair_photo_run();
    crate::priority::background();
    let s = ok(&run.output);
    let out = tempfile::tempdir().unwrap();
    assert!(s.contains("3 channel(s)"), "{s}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.out.join("report.json")).unwrap())
            .unwrap();
    let m = &report["metrics"];
    // Measured 0.821 / 12.03 dB / 11.99 dB with the area shadows the photo
    // chooses (0.803 / 11.74 / 11.42 with point shadows; the authors'
    // hand-tuned pipeline: 0.64 / 9.7 dB after the fit / 9.35 dB).
    assert!(m["zncc"].as_f64().unwrap() >= 0.80, "{m}");
    assert!(m["psnr_affine_db"].as_f64().unwrap() >= 11.4, "{m}");
    assert!(m["psnr_db"].as_f64().unwrap() >= 11.0, "{m}");
    assert_eq!(report["data_term"], "differences");
    for ch in report["channels"].as_array().unwrap() {
        // Gains the photo implies (1.4-3.0e8 fitted against the truth), a
        // positive ambient background known to within a percent.
        let g = ch["gain"].as_f64().unwrap();
        assert!((1.0e8..4.0e8).contains(&g), "{ch}");
        let (b, sd) = (
            ch["background"][0].as_f64().unwrap(),
            ch["background_sd"][0].as_f64().unwrap(),
        );
        assert!(b > 0.0 && sd < 0.25 * b, "{ch}");
        assert!(
            ch["lambda_rule"]
                .as_str()
                .unwrap()
                .starts_with("discrepancy"),
            "{ch}"
        );
    }
    // The photo as given fits T far better than any flip of it (measured
    // 3.1-4.1x), and nothing is wrong with it.
    let misfit: Vec<f64> = report["orientation"]["misfit"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_eq!(report["orientation"]["best"], "as-given");
    assert!(
        misfit[1..].iter().all(|m| *m > 2.0 * misfit[0]),
        "{misfit:?}"
    );
    assert_eq!(report["warnings"], serde_json::json!([]));
    let rec = npy::read(&run.out.join("recovered.npy")).unwrap();
    assert_eq!(rec.shape, vec![29, 36, 3]);
    // recovered.npy is top row first, as the authors stored their truth:
    // the two files correlate as they are, with no flip.
    let truth = npy::read(&data.join("truth_rgb.npy")).unwrap();
    let as_stored = polnlos::solve::metrics::zncc(&truth.data, &rec.data);
    assert!(as_stored >= 0.80, "{as_stored}");
    assert!((as_stored - m["zncc"].as_f64().unwrap()).abs() < 1e-9);
    // The same photo mirrored (columns reversed) is caught and named.
    let photo = npy::read(&data.join("measurement.npy")).unwrap();
    let mirrored: Vec<f64> = (0..126 * 126)
        .flat_map(|j| {
            let (r, c) = (j / 126, j % 126);
            let from = r * 126 + 125 - c;
            photo.data[3 * from..3 * from + 3].to_vec()
        })
        .collect();
    let m = out.path().join("mirrored.npy");
    npy::write_f64(&m, &[126 * 126, 3], &mirrored).unwrap();
    let mirrored = reconstruct_photo(&m, &out.path().join("mirrored"), None, &run.cache);
    ok(&mirrored);
    // The second call of the scene reads T from the cache, the same matrix:
    // its orientation check on the mirrored photo finds the same misfits
    // the first call's did for its flips.
    let mirrored_report: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out.path().join("mirrored/report.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(report["transport_cache"], "stored");
    assert_eq!(mirrored_report["transport_cache"], "hit");
    let m2 = &mirrored_report["orientation"]["misfit"];
    assert!(
        (m2[1].as_f64().unwrap() / misfit[0] - 1.0).abs() < 1e-9,
        "{m2} against {misfit:?}"
    );
    let err = String::from_utf8_lossy(&mirrored.stderr);
    assert!(
        err.contains("warning: the photo fits T better mirrored along u"),
        "{err}"
    );
    let png = crate::png::open(&run.out.join("recovered.png"));
    assert_eq!(
        (png.width, png.height, png.channels, png.bits),
        (36, 29, 3, 8)
    );
}

#[test]
fn a_photo_with_the_wrong_shape_or_values_is_refused_naming_the_file() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let dir = tempfile::tempdir().unwrap();
    let scene = root.join("config/photos/saunders-chair.toml");
    for (shape, data, says) in [
        (vec![100usize, 3], vec![1.0; 300], "neither [15876]"),
        (vec![15876, 5], vec![1.0; 15876 * 5], "C from 1 to 4"),
        (
            vec![15876],
            {
                // NaN marks an element not measured; an infinity is refused.
                let mut v = vec![1.0; 15876];
                v[7] = f64::INFINITY;
                v
            },
            "infinite",
        ),
    ] {
        let p = dir.path().join("m.npy");
        npy::write_f64(&p, &shape, &data).unwrap();
        let e = fails(&polnlos(&[
            "reconstruct",
            scene.to_str().unwrap(),
            "--photo",
            "--measurement",
            p.to_str().unwrap(),
            "--out",
            dir.path().join("out").to_str().unwrap(),
        ]));
        assert!(e.contains(says) && e.contains("m.npy"), "{says}: {e}");
    }
}
