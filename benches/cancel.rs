//! How soon each stage of a reconstruction ends once its stop flag is
//! raised: the T build, the Gram, an ADMM-TV solve with its automatic λ, a
//! photo's fit with its bootstrap, and a scene calibration's search
//! (`calibrate scene`, `POST /calibrations/scene`). The daemon's cancel and SIGTERM raise this flag; the job then
//! records its end within milliseconds of the stage returning.
//!
//! Run: `cargo bench --bench cancel`. Scene: the Brewster bench (two poses,
//! crossed polarizer), wall 96x96, scene 32x32, so that T is 18432 x 1024
//! and every stage takes long enough to be stopped in its middle. Each
//! stage runs once alone (its length), then five times with the flag raised
//! at 10 %, 30 %, 50 %, 70 % and 90 % of that length; printed: the length
//! and the latency from the flag to the stage's return (min, median, max).
//! Target on the 2-core bench machine: every latency under 0.5 s.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use polnlos::calibrate::scene::{Freedom, Placement, SceneFitOptions, Shot};
use polnlos::scene::Scene;
use polnlos::simulate::patterns::Pattern;
use polnlos::solve::gram::Gram;
use polnlos::solve::photo::{reconstruct_photo, PhotoSettings};
use polnlos::solve::reconstruct::{reconstruct, Context};
use polnlos::solve::{condition, SolveRequest};
use polnlos::stop::Stop;
use polnlos::transport::{build, build_with_progress, MemoryBudget, Transport};

fn scene() -> Scene {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("config/scenes/brewster-multi.toml");
    let text = std::fs::read_to_string(path)
        .expect("config/scenes/brewster-multi.toml")
        .replace("grid = [32, 32]", "grid = [96, 96]")
        .replace("grid = [8, 8]", "grid = [32, 32]");
    Scene::from_toml_str(&text).expect("bench scene")
}

/// Runs `stage` with a flag raised after `after` by a second thread; the
/// time from the flag to the stage's return.
fn latency(after: Duration, stage: &(dyn Fn(Stop<'_>) + Sync)) -> Duration {
    let flag = AtomicBool::new(false);
    let raised = std::sync::Mutex::new(None::<Instant>);
    std::thread::scope(|s| {
        s.spawn(|| {
            std::thread::sleep(after);
            *raised.lock().expect("not poisoned") = Some(Instant::now());
            flag.store(true, Ordering::SeqCst);
        });
        stage(Stop::on(&flag));
        let ended = Instant::now();
        // A stage that ended before the flag was not stopped: 0.
        let at = loop {
            if let Some(at) = *raised.lock().expect("not poisoned") {
                break at;
            }
            std::thread::sleep(Duration::from_millis(1));
        };
        ended.saturating_duration_since(at)
    })
}

/// One row: the stage's length alone and its latencies.
fn row(name: &str, stage: &(dyn Fn(Stop<'_>) + Sync)) {
    let t = Instant::now();
    stage(Stop::default());
    let alone = t.elapsed();
    let mut l: Vec<Duration> = [0.1, 0.3, 0.5, 0.7, 0.9]
        .iter()
        .map(|f| latency(alone.mul_f64(*f), stage))
        .collect();
    l.sort();
    println!(
        "| {name} | {:.3} | {:.3} | {:.3} | {:.3} |",
        alone.as_secs_f64(),
        l[0].as_secs_f64(),
        l[2].as_secs_f64(),
        l[4].as_secs_f64()
    );
}

fn main() {
    faer::set_global_parallelism(faer::Par::rayon(0));
    let s = scene();
    let t: Transport = build(&s, MemoryBudget::DEFAULT).expect("T");
    let i = t.apply(&Pattern::Letter.render(t.scene_grid()));
    println!("T {} x {}", t.rows(), t.cols());
    println!("| stage | alone s | latency min s | median s | max s |");
    println!("|---|---|---|---|---|");
    row("T build", &|stop| {
        let _ = build_with_progress(&s, MemoryBudget::DEFAULT, &|_| {}, stop);
    });
    row("Gram and its low-rank form", &|stop| {
        let _ = Gram::of_until(&t, stop);
    });
    let cond = condition(&t).expect("SVD");
    row("ADMM-TV, automatic λ", &|stop| {
        let req = SolveRequest::default();
        let ctx = Context {
            scene: "bench".into(),
            transport_seconds: 0.0,
            truth: None,
            stop,
        };
        let _ = reconstruct(&t, &i, None, &cond, &req, ctx);
    });
    row("photo fit and bootstrap", &|stop| {
        let settings = PhotoSettings {
            stop,
            ..PhotoSettings::default()
        };
        let _ = reconstruct_photo(&t, std::slice::from_ref(&i), None, &settings);
    });
    // The occluder bench (wall 32x32, scene 8x8), its occluder 1 cm off the
    // file, a calibration shot of the letter: a search of up to 80 T builds.
    let written = Scene::load_or_builtin(std::path::Path::new("occluder-crossed")).expect("scene");
    let mut off = Placement::default();
    off.set(Freedom::OccluderX, 0.01);
    let bench = off.moved(&written).expect("moved");
    let tb = build(&bench, MemoryBudget::DEFAULT).expect("T");
    let letter = Pattern::Letter.render(tb.scene_grid());
    let shot = Shot {
        channels: vec![tb.apply(&letter)],
        known: Some(vec![letter]),
    };
    row("scene calibration's search", &|stop| {
        let _ = SceneFitOptions::default().fit(&written, std::slice::from_ref(&shot), stop);
    });
}
