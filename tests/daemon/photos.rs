//! `POST /captures/import` over real HTTP on 127.0.0.1, the store through
//! its database file: a measurement or a photo taken elsewhere becomes a
//! capture, and its reconstruction (gain and background fitted) gives the
//! numbers of the CLI's `--photo` and of the camera capture it came from.
//! (Named so that libtest starts it after `daemon::in_process`: its chair
//! fits take both cores for half a minute, and the progressive test there
//! runs against frames arriving in real time.)

use std::path::{Path, PathBuf};
use std::time::Duration;

use serde_json::{json, Value};

use super::common::{config, scratch, InProcess};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// An in-process daemon that also knows the chair photo's scene.
fn chair_daemon(dir: &Path) -> InProcess {
    let scene = root().join("config/photos/saunders-chair.toml");
    let listed = format!("scene_files = [{:?}]", scene.display().to_string());
    let cfg = config(dir, &[("scene_files = []", &listed)]);
    InProcess::start(&cfg, &dir.join("data"))
}

/// The largest difference between two arrays of the same shape.
fn max_diff(a: &polnlos::files::npy::Array, b: &polnlos::files::npy::Array) -> f64 {
    assert_eq!(a.shape, b.shape);
    a.data
        .iter()
        .zip(&b.data)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

/// The chair's truth (`truth_rgb.npy`, as the authors stored it) as a
/// request's image: rows top first of `[red, green, blue]` in [0, 1].
fn chair_truth(data: &Path) -> Vec<Value> {
    let a = polnlos::files::npy::read(&data.join("truth_rgb.npy")).unwrap();
    assert_eq!(a.shape, vec![29, 36, 3]);
    a.data
        .chunks(36 * 3)
        .map(|row| {
            let pixels = row.chunks(3);
            json!(pixels
                .map(|p| p.iter().map(|v| v / 255.0).collect::<Vec<_>>())
                .collect::<Vec<_>>())
        })
        .collect()
}

fn recovered(d: &InProcess, rec: &Value) -> polnlos::files::npy::Array {
    let (s, bytes) = d.get_bytes(&format!("/reconstructions/{}/recovered.npy", rec["id"]));
    assert_eq!(s, 200);
    polnlos::files::npy::decode(&bytes).unwrap()
}

/// Saunders et al.'s chair photo (`[rows, 3]`) imported over HTTP and
/// reconstructed with nothing but its scene and captures gives the CLI's
/// `reconstruct --photo` result, and says its radiometry was fitted.
#[test]
fn the_chair_photo_imported_over_http_reconstructs_as_the_cli_photo_mode() {
    // No camera here, and no Aravis lock: its two chair fits (CLI and
    // daemon, with both shadow models) take both cores for half a minute,
    // but in the background class (`InProcess::start`, and the CLI it
    // starts inherits it), so a camera test's real-time capture takes a
    // core from them at once. Holding the lock put a minute into the
    // chain of the camera tests, which run one at a time.
    let dir = scratch();
    let d = chair_daemon(dir.path());
    let data = root().join("tests/data/saunders-chair");
    let bytes = std::fs::read(data.join("measurement.npy")).unwrap();
    let started = std::time::Instant::now();
    let (s, body, loc) = d.post_bytes(
        "/captures/import?scene=saunders-chair&pose=photo&name=measurement.npy",
        &bytes,
    );
    assert_eq!(s, 201, "{body}");
    let cap: Value = serde_json::from_str(&body).unwrap();
    assert_eq!(loc.as_deref(), Some(&*format!("/captures/{}", cap["id"])));
    assert_eq!(cap["state"], "done");
    assert_eq!(cap["kind"], "light");
    assert_eq!(cap["channels"], json!([{"analyzer": "none"}]));
    let import = &cap["import"];
    assert_eq!(import["format"], "npy");
    assert_eq!(import["name"], "measurement.npy");
    assert_eq!(import["colours"], 3);
    assert_eq!(import["bytes"], bytes.len());
    assert_eq!(import["sha256"].as_str().unwrap().len(), 64);
    // Listed like any capture, and read back from the catalogue.
    assert_eq!(
        d.json(&format!("/captures/{}", cap["id"]))["import"],
        *import
    );
    // The monitor's image as the authors stored it (top row first), as the
    // request's truth; one of another size is refused naming both sizes.
    let truth = chair_truth(&data);
    let wrong = json!({"scene": "saunders-chair", "captures": [cap["id"]],
        "truth": {"image": truth[1..].to_vec()}});
    let (s, body, _) = d.post("/reconstructions", &wrong.to_string());
    assert_eq!(s, 422, "{body}");
    assert!(
        body.contains("truth is 28 x 36 (rows x columns); the scene grid is 29 x 36"),
        "{body}"
    );
    let rec = d.run_job(
        "/reconstructions",
        &json!({"scene": "saunders-chair", "captures": [cap["id"]], "truth": {"image": truth}})
            .to_string(),
        Duration::from_secs(300),
    );
    assert_eq!(rec["state"], "done", "{rec}");
    let (s, png) = d.get_bytes(&format!("/reconstructions/{}/truth.png", rec["id"]));
    assert_eq!(s, 200);
    std::fs::write(dir.path().join("truth.png"), &png).unwrap();
    let shown = polnlos::files::image::read_gray(&dir.path().join("truth.png")).unwrap();
    assert_eq!((shown.width, shown.height), (36, 29));
    // Shown as given: its first row is the image's first row (the top).
    for (k, px) in truth[0].as_array().unwrap().iter().enumerate() {
        let [r, g, b] = [0, 1, 2].map(|c| px[c].as_f64().unwrap());
        let luma = 0.2126 * r + 0.7152 * g + 0.0722 * b;
        assert!((shown.data[k] - luma).abs() < 2e-3, "column {k}");
    }
    // A measurement, not a bound: timings are the benchmarks' (the note
    // records it).
    println!(
        "chair photo: import to done in {:.2} s (T {:.2} s, model {:.2} s, solves {:.2} s, the job {:.2} s)",
        started.elapsed().as_secs_f64(),
        rec["report"]["transport_seconds"].as_f64().unwrap_or(f64::NAN),
        rec["report"]["model_seconds"].as_f64().unwrap_or(f64::NAN),
        rec["report"]["solve_seconds"].as_f64().unwrap_or(f64::NAN),
        rec["report"]["total_seconds"].as_f64().unwrap_or(f64::NAN),
    );
    let report = &rec["report"];
    assert_eq!(report["radiometry"]["mode"], "fitted", "{report}");
    assert_eq!(report["radiometry"]["given"], false);
    let reason = report["radiometry"]["reason"].as_str().unwrap();
    assert!(reason.contains("was imported"), "{reason}");
    assert_eq!(report["data_term"], "differences");
    assert_eq!(report["channels"].as_array().unwrap().len(), 3);
    let ours = recovered(&d, &rec);
    assert_eq!(ours.shape, vec![29, 36, 3]);
    // The CLI on the same photo, with the truth for the metrics (one run
    // the offline CLI test shares).
    let cli = crate::core::cli::chair_photo_run();
    assert!(
        cli.output.status.success(),
        "{}",
        String::from_utf8_lossy(&cli.output.stderr)
    );
    let theirs = polnlos::files::npy::read(&cli.out.join("recovered.npy")).unwrap();
    let diff = max_diff(&ours, &theirs);
    assert!(diff <= 1e-9, "daemon and CLI differ by {diff:e}");
    // fitted.npy (x = g l, top row first) the same in both folders too.
    let read = |p: &Path| polnlos::files::npy::read(p).unwrap();
    let fitted = dir
        .path()
        .join(format!("data/reconstructions/{}/fitted.npy", rec["id"]));
    let (ours, theirs) = (read(&fitted), read(&cli.out.join("fitted.npy")));
    let diff = max_diff(&ours, &theirs);
    assert!(
        diff <= 1e-9 * theirs.data.iter().fold(0.0, |m, v| v.abs().max(m)),
        "fitted.npy: daemon and CLI differ by {diff:e}"
    );
    let cli_report: Value =
        serde_json::from_str(&std::fs::read_to_string(cli.out.join("report.json")).unwrap())
            .unwrap();
    let m = &cli_report["metrics"];
    assert!(m["zncc"].as_f64().unwrap() >= 0.80, "{m}");
    assert!(m["psnr_affine_db"].as_f64().unwrap() >= 11.4, "{m}");
    // Scored against the truth image of the request, the same numbers.
    for k in ["zncc", "psnr_db", "psnr_affine_db", "ssim"] {
        let (a, b) = (report["metrics"][k].as_f64(), m[k].as_f64());
        assert!((a.unwrap() - b.unwrap()).abs() <= 1e-9, "{k}: {a:?} {b:?}");
    }
    // The fitted gains and backgrounds are the same numbers too.
    for (a, b) in report["channels"]
        .as_array()
        .unwrap()
        .iter()
        .zip(cli_report["channels"].as_array().unwrap())
    {
        let (ga, gb) = (a["gain"].as_f64().unwrap(), b["gain"].as_f64().unwrap());
        assert!((ga - gb).abs() <= 1e-9 * gb, "{ga} {gb}");
    }
}

/// A file that does not fit its scene and pose is refused with a 4xx that
/// says what is wrong, and nothing is stored.
#[test]
fn an_import_that_does_not_fit_is_refused_and_nothing_is_stored() {
    let dir = scratch();
    let d = chair_daemon(dir.path());
    let npy = |shape: &[usize], fill: f64| {
        let dir = scratch();
        let p = dir.path().join("m.npy");
        let n: usize = shape.iter().product();
        polnlos::files::npy::write_f64(&p, shape, &vec![fill; n]).unwrap();
        std::fs::read(p).unwrap()
    };
    let good = npy(&[15876, 3], 1.0);
    let cases: Vec<(String, Vec<u8>, u16, &str)> = vec![
        (
            "scene=nowhere&pose=photo".into(),
            good.clone(),
            404,
            "nowhere",
        ),
        (
            "scene=saunders-chair&pose=B".into(),
            good.clone(),
            422,
            "its poses: photo",
        ),
        (
            "scene=saunders-chair&pose=photo".into(),
            npy(&[15875, 3], 1.0),
            422,
            "[15876] or [15876, C]",
        ),
        (
            "scene=saunders-chair&pose=photo".into(),
            npy(&[15876, 5], 1.0),
            422,
            "C from 1 to 4",
        ),
        (
            "scene=saunders-chair&pose=photo".into(),
            npy(&[15876], f64::INFINITY),
            422,
            "finite",
        ),
        (
            "scene=saunders-chair&pose=photo".into(),
            npy(&[15876], f64::NAN),
            422,
            "no measured value",
        ),
        (
            "scene=saunders-chair&pose=photo".into(),
            b"hello, world".to_vec(),
            422,
            "neither a .npy",
        ),
        (
            "scene=saunders-chair&pose=photo".into(),
            Vec::new(),
            422,
            "empty",
        ),
        (
            "scene=saunders-chair&pose=photo&bayer=RG".into(),
            good.clone(),
            422,
            "a .npy is a measurement already",
        ),
        (
            "scene=saunders-chair&pose=photo&bayer=XY".into(),
            good.clone(),
            422,
            "RG, GR, GB or BG",
        ),
        (
            "scene=saunders-chair&pose=photo&polarizer_deg=45".into(),
            good.clone(),
            422,
            "no block at polarizer_deg 45",
        ),
        (
            "scene=saunders-chair&pose=photo&colour=red".into(),
            good.clone(),
            400,
            "colour",
        ),
        (
            // A bad query with a large file: answered once the file is
            // read (an answer sent while the client still wrote it cut the
            // connection: a broken pipe, not the answer).
            "scene=saunders-chair&pose=photo&colour=red".into(),
            vec![0u8; 16 << 20],
            400,
            "colour",
        ),
        (
            // A PNG needs the pose's homography to be sampled at the wall.
            "scene=saunders-chair&pose=photo".into(),
            polnlos::files::image::encode_png16(4, 4, &[1000; 16]).unwrap(),
            422,
            "POST /calibrations",
        ),
    ];
    for (query, body, status, says) in cases {
        let (s, b, _) = d.post_bytes(&format!("/captures/import?{query}"), &body);
        assert_eq!(s, status, "{query}: {b}");
        assert!(b.contains(says), "{query}: {b}");
    }
    let (s, b) = d.get("/captures");
    assert_eq!(s, 200);
    assert_eq!(serde_json::from_str::<Value>(&b).unwrap(), json!([]));
    // A measurement that fits is stored after them, as capture 1.
    let (s, b, _) = d.post_bytes("/captures/import?scene=saunders-chair&pose=photo", &good);
    assert_eq!(s, 201, "{b}");
    assert_eq!(serde_json::from_str::<Value>(&b).unwrap()["id"], 1);
}

/// A camera frame downloaded from the daemon and imported again, as a TIFF
/// and as a 16-bit PNG, is sampled through the pose's homography as the
/// capture was: the three reconstructions (fitted) are the same image.
#[test]
fn a_camera_frame_imported_as_tiff_or_png_reconstructs_as_its_capture() {
    let dir = scratch();
    let cfg = config(dir.path(), &[]);
    let d = InProcess::start(&cfg, &dir.path().join("data"));
    let cap = d.run_job(
        "/captures",
        &json!({"scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0,
                "exposure_us": 20000, "frames": 1, "dark_frames": 0})
        .to_string(),
        Duration::from_secs(60),
    );
    assert_eq!(cap["state"], "done", "{cap}");
    let fitted = |ids: &[&Value]| {
        d.run_job(
            "/reconstructions",
            &json!({"scene": "brewster-crossed", "captures": ids, "radiometry": "fitted"})
                .to_string(),
            Duration::from_secs(120),
        )
    };
    let from_camera = fitted(&[&cap["id"]]);
    assert_eq!(from_camera["state"], "done", "{from_camera}");
    assert_eq!(from_camera["report"]["radiometry"]["given"], true);
    let (s, tiff) = d.get_bytes(&format!("/captures/{}/frame.tiff", cap["id"]));
    assert_eq!(s, 200);
    let frame = polnlos::files::frames::decode_frames(&tiff).unwrap();
    let dn: Vec<u16> = frame.stack.mean.iter().map(|v| *v as u16).collect();
    let png =
        polnlos::files::image::encode_png16(frame.stack.width, frame.stack.height, &dn).unwrap();
    let want = recovered(&d, &from_camera);
    for (format, body) in [("tiff", tiff), ("png", png)] {
        let (s, b, _) = d.post_bytes(
            "/captures/import?scene=brewster-crossed&pose=A&polarizer_deg=0",
            &body,
        );
        assert_eq!(s, 201, "{format}: {b}");
        let imported: Value = serde_json::from_str(&b).unwrap();
        assert_eq!(imported["import"]["format"], format);
        let rec = d.run_job(
            "/reconstructions",
            &json!({"scene": "brewster-crossed", "captures": [imported["id"]]}).to_string(),
            Duration::from_secs(120),
        );
        assert_eq!(rec["state"], "done", "{rec}");
        assert_eq!(rec["report"]["radiometry"]["mode"], "fitted");
        let diff = max_diff(&recovered(&d, &rec), &want);
        assert!(
            diff <= 1e-9,
            "{format}: differs from the capture by {diff:e}"
        );
        // A fitted solve takes no other solver.
        let (s, b, _) = d.post(
            "/reconstructions",
            &json!({"scene": "brewster-crossed", "captures": [imported["id"]], "partial": true,
                    "solver": "lsq", "radiometry": "fitted"})
            .to_string(),
        );
        assert_eq!(s, 422, "{b}");
        assert!(b.contains("admm-tv"), "{b}");
    }
}
