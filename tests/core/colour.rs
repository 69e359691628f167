//! A colour (Bayer) sensor against monochrome captures of each colour: the
//! same simulated wall images, per-pixel shot and read noise, measured as
//! captures are (each colour over its own pixels) and reconstructed with
//! the automatic λ.

use polnlos::measure::colour::{BayerPattern, Colour};
use polnlos::measure::{assemble, assemble_colour, CaptureFrames, PixelMaps};
use polnlos::scene::{Frame, FrameGeometry, Scene};
use polnlos::simulate::camera::{expose, render};
use polnlos::simulate::patterns::Pattern;
use polnlos::solve::lambda::NoiseLevel;
use polnlos::solve::metrics::compare;
use polnlos::solve::reconstruct::Context;
use polnlos::solve::{condition, reconstruct, SolveRequest};
use polnlos::transport::{blocks_of, build, MemoryBudget, Transport};
use rand::SeedableRng;

/// Electrons at the brightest pixel of a colour's wall image.
const PHOTONS: f64 = 2e4;
/// Read noise, electrons RMS.
const READ_NOISE: f64 = 5.0;

/// The scene, its `T` and each colour's truth: a different pattern in each,
/// so a channel measured from another colour's pixels would show.
fn bench() -> (Scene, Transport, [Vec<f64>; 3]) {
    let scene = Scene::builtin("brewster-crossed").unwrap().unwrap();
    let t = build(&scene, MemoryBudget::DEFAULT).unwrap();
    let grid = t.scene_grid();
    let disk = Pattern::Disk.render(grid);
    let ring: Vec<f64> = disk.iter().map(|v| 1.0 - v).collect();
    let truth = [disk, Pattern::Letter.render(grid), ring];
    (scene, t, truth)
}

/// The PSNR of each colour's reconstruction from `captures`, measured per colour.
fn psnr(
    t: &Transport,
    truth: &[Vec<f64>; 3],
    measure: impl Fn(usize) -> polnlos::measure::Measurement,
) -> [f64; 3] {
    let cond = condition(t).unwrap();
    [0, 1, 2].map(|c| {
        let m = measure(c);
        let solved = reconstruct(
            t,
            &m.i,
            Some(NoiseLevel::measured(m.variance.unwrap())),
            &cond,
            &SolveRequest::default(),
            Context::default(),
        )
        .unwrap();
        compare(t.scene_grid(), &truth[c], &solved.image).psnr_db
    })
}

#[test]
fn a_bayer_capture_reconstructs_each_colour_as_its_pixels_allow() {
    crate::priority::background();
    let (scene, t, truth) = bench();
    let blocks = blocks_of(&scene);
    assert_eq!(blocks.len(), 1);
    let geometry = FrameGeometry::plain(512, 512);
    let clean: Vec<Frame> = truth
        .iter()
        .map(|l| render(&scene, l, geometry).remove(0).1.unwrap())
        .collect();
    let peak = clean
        .iter()
        .flat_map(|f| f.pixels.iter())
        .fold(0.0f32, |m, &v| m.max(v));
    let per_unit = PHOTONS / f64::from(peak);
    let pattern = BayerPattern::RG;
    let pose = blocks[0].pose.clone();
    let channels = vec![blocks[0].channel];
    let capture = |name: &str, frame: &Frame, scale: f64, seed: u64| {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        CaptureFrames::exposure(
            name.into(),
            pose.clone(),
            channels.clone(),
            expose(frame, per_unit * scale, READ_NOISE, &mut rng),
            per_unit * scale,
        )
    };
    // The Bayer sensor's raw frame: each pixel its own colour's image.
    let mut raw = Frame::zeros(512, 512);
    for y in 0..512 {
        for x in 0..512 {
            let c = pattern.colour_at(x as i64, y as i64) as usize;
            raw.pixels[y * 512 + x] = clean[c].pixels[y * 512 + x];
        }
    }
    let maps = PixelMaps::default();
    // Noiseless, each colour of the raw frame measures what a monochrome
    // frame of that colour's image measures, far below the noise: measured
    // 0.10, 0.02 and 0.03 of it (red, green, blue). The plain mean over a
    // colour's own pixels, half a pixel off each element's centroid, was
    // 0.72, 0.18 and 1.26 of it.
    let noiseless = |frame: &Frame, bayer: bool| {
        let mut c = CaptureFrames::exposure(
            "noiseless".into(),
            pose.clone(),
            channels.clone(),
            (frame.clone(), Frame::zeros(512, 512)),
            1.0,
        );
        c.bayer = bayer.then_some(pattern);
        c
    };
    let mut noisy = capture("noisy", &raw, 1.0, 0);
    noisy.bayer = Some(pattern);
    for (c, colour) in Colour::ALL.into_iter().enumerate() {
        let from_raw = assemble_colour(
            &scene,
            &blocks,
            &[noiseless(&raw, true)],
            &maps,
            Some(colour),
        );
        let mono = assemble(&scene, &blocks, &[noiseless(&clean[c], false)]).unwrap();
        let v = assemble_colour(&scene, &blocks, &[noisy.clone()], &maps, Some(colour))
            .unwrap()
            .variance
            .unwrap();
        let sd = (v.iter().sum::<f64>() / v.len() as f64).sqrt();
        let d = from_raw
            .unwrap()
            .i
            .iter()
            .zip(&mono.i)
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f64>();
        let rms = (d / mono.i.len() as f64).sqrt();
        assert!(
            rms < 0.2 * sd,
            "{colour:?}: {rms:.3e} against the noise {sd:.3e}"
        );
    }
    let (mut bayer, mut same_exposure, mut same_photons) = ([0.0; 3], [0.0; 3], [0.0; 3]);
    let seeds = 5;
    for seed in 0..seeds {
        let mut shot = capture("bayer", &raw, 1.0, seed);
        shot.bayer = Some(pattern);
        let b = psnr(&t, &truth, |c| {
            assemble_colour(
                &scene,
                &blocks,
                &[shot.clone()],
                &maps,
                Some(Colour::ALL[c]),
            )
            .unwrap()
        });
        // A monochrome camera behind each colour's filter, same exposure:
        // every pixel sees the colour (4x red's and blue's pixels, 2x green's).
        let m = psnr(&t, &truth, |c| {
            assemble(
                &scene,
                &blocks,
                &[capture("mono", &clean[c], 1.0, 100 + seed)],
            )
            .unwrap()
        });
        // The same with the exposure cut to the colour's share of a Bayer
        // cell: as many photons per element as the Bayer channel has.
        let share = [0.25, 0.5, 0.25];
        let p = psnr(&t, &truth, |c| {
            let shot = capture("mono", &clean[c], share[c], 200 + seed);
            assemble(&scene, &blocks, &[shot]).unwrap()
        });
        for c in 0..3 {
            bayer[c] += b[c] / seeds as f64;
            same_exposure[c] += m[c] / seeds as f64;
            same_photons[c] += p[c] / seeds as f64;
        }
    }
    for c in 0..3 {
        let what = format!(
            "{:?}: bayer {bayer:?}, mono {same_exposure:?}, equal photons {same_photons:?}",
            Colour::ALL[c]
        );
        // As well as a monochrome capture of the same photons per element
        // (measured 27.5 / 15.3 / 27.7 dB against 26.9 / 15.2 / 28.1).
        assert!(bayer[c] > same_photons[c] - 0.5, "{what}");
        // Behind one of the same exposure (27.5 / 15.7 / 29.0 dB) by no more
        // than its pixel share's noise: 10 log10(4) = 6 dB for red and
        // blue, 3 dB for green.
        let share_db = 10.0 * [4.0f64, 2.0, 4.0][c].log10();
        assert!(same_exposure[c] - bayer[c] < share_db, "{what}");
        // Each colour is its own pattern, well resolved.
        assert!(bayer[c] > 14.0, "{what}");
    }
}
