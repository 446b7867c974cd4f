//! Property-based fuzzing of the scenario loader (issue 13): random byte mutations of every
//! bundled scenario file, and random override trees over the schema's keys with values of every
//! TOML type (including NaN, infinities, huge and negative numbers, empty and nested arrays),
//! go through parsing, the arm's URDF and validation. Each ends in a value or an error that names
//! the file; never a panic, never a hang (a fixed case budget, every loop bounded by the checks).

mod common;

use std::path::{Path, PathBuf};

use aift::scenario::{LoadedScenario, parse_scenario};
use aift::sensors::ChannelLayout;
use proptest::prelude::*;

fn bundled() -> Vec<(PathBuf, String)> {
    common::toml_files("assets/scenarios")
        .into_iter()
        .map(|p| {
            let t = std::fs::read_to_string(&p).unwrap();
            (p, t)
        })
        .collect()
}

/// Parse, load the arm and validate; an error must name the scenario file.
fn load_and_validate(text: &str, path: &Path, overrides: &[String]) {
    let scenario = match parse_scenario(text, path, overrides) {
        Ok(s) => s,
        Err(e) => {
            let m = e.to_string();
            assert!(
                m.contains(&path.display().to_string()) || m.starts_with("--set"),
                "{m}"
            );
            return;
        }
    };
    let loaded = LoadedScenario {
        scenario,
        path: path.to_path_buf(),
        base_dir: path.parent().map(Path::to_path_buf),
    };
    let model = match loaded.arm_model() {
        Ok(m) => m,
        Err(e) => {
            assert!(e.to_string().contains(&path.display().to_string()), "{e}");
            return;
        }
    };
    let layout = ChannelLayout::new(model.joints.len(), loaded.scenario.camera.model);
    if let Err(e) = loaded.scenario.validate(&layout, &loaded.path) {
        assert!(e.to_string().contains(&path.display().to_string()), "{e}");
    }
}

/// Every key of a scenario as dotted paths (arrays of tables indexed), from its resolved form,
/// with its value there (None for keys the resolved form leaves out).
fn keys() -> Vec<(String, Option<toml::Value>)> {
    fn walk(prefix: &str, v: &toml::Value, out: &mut Vec<(String, Option<toml::Value>)>) {
        match v {
            toml::Value::Table(t) => {
                for (k, v) in t {
                    let key = if prefix.is_empty() {
                        k.clone()
                    } else {
                        format!("{prefix}.{k}")
                    };
                    out.push((key.clone(), Some(v.clone())));
                    walk(&key, v, out);
                }
            }
            toml::Value::Array(a) => {
                for (i, v) in a.iter().enumerate().take(3) {
                    let key = format!("{prefix}[{i}]");
                    out.push((key.clone(), Some(v.clone())));
                    walk(&key, v, out);
                }
            }
            _ => {}
        }
    }
    let (_, text) = bundled()
        .into_iter()
        .find(|(p, _)| p.ends_with("paper_encoder_freeze.toml"))
        .unwrap();
    let path = common::repo("assets/scenarios/paper_encoder_freeze.toml");
    let s = parse_scenario(&text, &path, &[]).unwrap();
    let value = toml::Value::try_from(&s).unwrap();
    let mut out = Vec::new();
    walk("", &value, &mut out);
    // Keys the resolved form leaves out (absent options) and a few that do not exist.
    out.extend(
        [
            "initial.qd",
            "gp.model",
            "gp.training_box",
            "detector.calibration",
            "kalman.acceleration_noise",
            "controller.kappa_u",
            "faults[0].end",
            "faults[1]",
            "targets[5]",
            "nonexistent",
            "robot.nonexistent",
        ]
        .map(|k| (k.to_string(), None)),
    );
    out
}

/// A number near the edges: zero, signs, tiny, huge, non-finite, or a scale of the original.
fn number(original: f64) -> impl Strategy<Value = String> {
    prop_oneof![
        prop::sample::select(vec![
            0.0,
            -1.0,
            1e308,
            -1e308,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            1e-320,
        ]),
        (-1e6f64..1e6).prop_map(move |k| original * k),
        (-30i32..30).prop_map(move |e| original * 10f64.powi(e)),
    ]
    .prop_map(|v| {
        if v.is_nan() {
            "nan".into()
        } else if v.is_infinite() {
            if v > 0.0 { "inf".into() } else { "-inf".into() }
        } else {
            format!("{v:?}")
        }
    })
}

/// A value of the key's own type (numbers and arrays of numbers perturbed), or of any type.
fn typed_value(original: Option<toml::Value>) -> BoxedStrategy<String> {
    match original {
        Some(toml::Value::Float(f)) => prop_oneof![4 => number(f), 1 => value()].boxed(),
        Some(toml::Value::Integer(i)) => prop_oneof![
            3 => prop::sample::select(vec![0i64, -1, 1, 2, i64::MAX, i64::MIN, 1_000_000_000])
                .prop_map(|v| v.to_string()),
            2 => (0i64..1000).prop_map(move |k| (i.saturating_mul(k)).to_string()),
            1 => value(),
        ]
        .boxed(),
        Some(toml::Value::Array(a)) if a.iter().all(|v| v.is_float()) => {
            let n = a.len();
            prop_oneof![
                4 => prop::collection::vec(number(1.0), n..=n).prop_map(|v| format!("[{}]", v.join(", "))),
                1 => prop::collection::vec(number(1.0), 0..12).prop_map(|v| format!("[{}]", v.join(", "))),
                1 => value(),
            ]
            .boxed()
        }
        _ => value().boxed(),
    }
}

fn value() -> impl Strategy<Value = String> {
    prop_oneof![
        any::<i64>().prop_map(|v| v.to_string()),
        prop::sample::select(vec![
            "0", "-1", "1e308", "-1e308", "nan", "inf", "-inf", "1e-320", "0.0", "-0.0",
            "4294967296", "18446744073709551615", "1000000000000",
        ])
        .prop_map(String::from),
        any::<f64>().prop_map(|v| format!("{v:?}")),
        any::<bool>().prop_map(|v| v.to_string()),
        "[a-z_./]{0,12}".prop_map(|s| format!("\"{s}\"")),
        prop::sample::select(vec![
            "[]", "[1.0]", "[0.0, 0.0]", "[1e300, -1e300, 0.0]", "[[1.0, 2.0]]", "[\"x\"]",
            "{}", "{ q = [0.0, 0.0], time = 1.0 }",
            "[{ channel = \"enc1\", kind = \"freeze\", start = 1.0 }]",
            "[{ channel = \"cam\", kind = \"spikes\", probability = 2.0, magnitude = 1e300, start = 0.0 }]",
            "\"../../../../dev/zero\"", "\"/dev/zero\"", "\"/proc/self/mem\"",
        ])
        .prop_map(String::from),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 300, .. ProptestConfig::default() })]

    /// Random byte edits (replace, insert, delete) of a bundled scenario.
    #[test]
    fn mutated_scenario_files_never_panic(
        file in 0usize..64,
        edits in prop::collection::vec((any::<u16>(), any::<u8>(), 0u8..3), 1..8),
    ) {
        let files = bundled();
        let (path, text) = &files[file % files.len()];
        let mut bytes = text.clone().into_bytes();
        for (at, byte, op) in edits {
            let i = at as usize % (bytes.len() + 1);
            match op {
                0 if i < bytes.len() => bytes[i] = byte,
                1 => bytes.insert(i, byte),
                _ if i < bytes.len() => { bytes.remove(i); }
                _ => {}
            }
        }
        let text = String::from_utf8_lossy(&bytes).into_owned();
        load_and_validate(&text, path, &[]);
    }

    /// Random override trees: 1 to 3 keys of the schema set to values of any type.
    #[test]
    fn random_overrides_never_panic(
        picks in prop::collection::vec(
            prop::sample::select(keys()).prop_flat_map(|(k, v)| {
                typed_value(v).prop_map(move |value| format!("{k}={value}"))
            }),
            1..4,
        ),
    ) {
        let overrides = picks;
        let path = common::repo("assets/scenarios/paper_encoder_freeze.toml");
        let text = std::fs::read_to_string(&path).unwrap();
        load_and_validate(&text, &path, &overrides);
    }
}
