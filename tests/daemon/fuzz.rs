//! The fuzz targets of `fuzz/` on stable, in the ordinary test suite: every
//! corpus file, then a fixed-seed batch of mutations of each (byte flips,
//! insertions, truncations, splices of interesting tokens). A panic here is a
//! crash a client or a file could cause. Longer, coverage-guided runs:
//! `cargo fuzz run <target>` in `fuzz/` (see the README).

#[path = "../../fuzz/fuzz_targets/parsers.rs"]
mod parsers;

use rand::{Rng, SeedableRng};

type Target = fn(&[u8]);

const TARGETS: [(&str, Target); 11] = [
    ("scene_toml", parsers::scene_toml),
    ("npy", parsers::npy),
    ("capture_json", parsers::capture_json),
    ("reconstruction_json", parsers::reconstruction_json),
    ("settings_json", parsers::settings_json),
    ("plan_json", parsers::plan_json),
    ("config_toml", parsers::config_toml),
    ("wall_calibration_json", parsers::wall_calibration_json),
    ("calibration_json", parsers::calibration_json),
    ("frames_tiff", parsers::frames_tiff),
    ("elliptec_reply", parsers::elliptec_reply),
];

/// Tokens that reach edge cases of these formats.
const TOKENS: [&[u8]; 18] = [
    b"1e308",
    b"-1",
    b"4294967296",
    b"18446744073709551615",
    b"nan",
    b"inf",
    b"[]",
    b"{}",
    b"\"",
    b"\\u0000",
    b"(",
    b")",
    b",",
    b"null",
    b"[[",
    b"\x93NUMPY\x02\x00",
    b"II*\x00",
    b"\xff\xff\xff\x7f",
];

fn mutate(rng: &mut rand_chacha::ChaCha8Rng, seed: &[u8]) -> Vec<u8> {
    let mut b = seed.to_vec();
    for _ in 0..rng.random_range(1..6) {
        let at = if b.is_empty() {
            0
        } else {
            rng.random_range(0..b.len())
        };
        match rng.random_range(0..5) {
            0 if !b.is_empty() => b[at] = rng.random(),
            1 => b.truncate(at),
            2 => {
                let t = TOKENS[rng.random_range(0..TOKENS.len())];
                b.splice(at..at, t.iter().copied());
            }
            3 if !b.is_empty() => {
                let end = (at + rng.random_range(1..16)).min(b.len());
                b.drain(at..end);
            }
            _ => {
                // Replace a run of digits with a huge number.
                let end = (at..b.len())
                    .find(|&i| !b[i].is_ascii_digit())
                    .unwrap_or(b.len());
                b.splice(at..end, b"99999999999999999999".iter().copied());
            }
        }
    }
    b
}

#[test]
fn every_parser_survives_its_corpus_and_mutations() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/corpus");
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(8);
    for (name, target) in TARGETS {
        let seeds: Vec<Vec<u8>> = std::fs::read_dir(root.join(name))
            .unwrap_or_else(|e| panic!("fuzz/corpus/{name}: {e}"))
            .flatten()
            .map(|e| std::fs::read(e.path()).unwrap())
            .collect();
        assert!(!seeds.is_empty(), "fuzz/corpus/{name} is empty");
        let mut runs = 0;
        for seed in &seeds {
            target(seed);
            for _ in 0..1500 {
                target(&mutate(&mut rng, seed));
                runs += 1;
            }
        }
        for _ in 0..500 {
            let n = rng.random_range(0..256);
            let bytes: Vec<u8> = (0..n).map(|_| rng.random()).collect();
            target(&bytes);
            runs += 1;
        }
        println!(
            "{name}: {} corpus files, {runs} mutated and random inputs",
            seeds.len()
        );
    }
}

/// JSON values whose objects use the request bodies' own field names, so
/// that most generated bodies get past "unknown field" to the values.
fn json_value() -> impl proptest::strategy::Strategy<Value = serde_json::Value> {
    use proptest::prelude::*;
    const KEYS: [&str; 24] = [
        "scene",
        "pose",
        "polarizer_deg",
        "exposure_us",
        "exposure",
        "gain",
        "frames",
        "dark_frames",
        "dark_capture",
        "pixel_format",
        "region",
        "binning",
        "trigger",
        "kind",
        "captures",
        "solver",
        "lambda",
        "max_iter",
        "tol",
        "truth",
        "source",
        "sources",
        "capture",
        "target",
    ];
    let leaf = prop_oneof![
        Just(serde_json::Value::Null),
        any::<bool>().prop_map(serde_json::Value::from),
        any::<i64>().prop_map(serde_json::Value::from),
        any::<u32>().prop_map(serde_json::Value::from),
        any::<f64>().prop_map(serde_json::Value::from),
        "[a-zA-Z0-9 -]{0,12}".prop_map(serde_json::Value::from),
        proptest::sample::select(vec![
            "auto",
            "dark",
            "light",
            "software",
            "free",
            "Mono8",
            "Mono16",
            "admm-tv",
            "letter",
            "brewster-crossed",
            "A"
        ])
        .prop_map(serde_json::Value::from),
    ];
    leaf.prop_recursive(3, 24, 6, |inner| {
        prop_oneof![
            proptest::collection::vec(inner.clone(), 0..5).prop_map(serde_json::Value::Array),
            proptest::collection::btree_map(proptest::sample::select(KEYS.to_vec()), inner, 0..6)
                .prop_map(|m| serde_json::Value::Object(
                    m.into_iter().map(|(k, v)| (k.to_string(), v)).collect()
                )),
        ]
    })
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig { cases: 2000, rng_seed: proptest::test_runner::RngSeed::Fixed(8), ..Default::default() })]
    /// Any JSON with the bodies' field names: each parser answers or errs, never panics.
    #[test]
    fn any_json_body_is_parsed_or_refused(v in json_value()) {
        let bytes = serde_json::to_vec(&v).unwrap();
        parsers::capture_json(&bytes);
        parsers::reconstruction_json(&bytes);
        parsers::settings_json(&bytes);
        parsers::plan_json(&bytes);
        parsers::wall_calibration_json(&bytes);
        parsers::calibration_json(&bytes);
    }
}
