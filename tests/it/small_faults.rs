//! Issue 19's small ones through the binary: the `prior:` failure in words with the sentence
//! counts (checksum errors included), and `gps decode | head` ending quietly. (`rectify
//! --rotation` with a non-rotation is in tests/rectify_reference.rs, `retry-max-s = inf` in
//! tests/validate_cli.rs.) On the same scene, the node's `[refine] sampling = "pv"` end to end.

use crate::common;

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::OnceLock;

const BIN: &str = env!("CARGO_BIN_EXE_infraloc");

fn scene() -> &'static Path {
    static SCENE: OnceLock<(tempfile::TempDir, PathBuf)> = OnceLock::new();
    &SCENE
        .get_or_init(|| {
            let d = tempfile::tempdir().unwrap();
            let dir = d.path().join("scene");
            common::simulate(BIN, &dir, &["--seed", "3", "--preset", "small"]);
            (d, dir)
        })
        .1
}

#[test]
fn prior_failure_counts_the_sentences_in_words() {
    let w = tempfile::tempdir().unwrap();
    // The scene's log with every checksum broken, plus two lines of noise.
    let log = std::fs::read_to_string(scene().join("gps.nmea")).unwrap();
    let broken: String = log
        .lines()
        .map(|l| match l.rsplit_once('*') {
            Some((body, _)) => format!("{body}*00\n"),
            None => format!("{l}\n"),
        })
        .collect();
    let n = log.lines().filter(|l| l.starts_with('$')).count();
    let nmea = w.path().join("bad.nmea");
    std::fs::write(&nmea, format!("{broken}hello\n$GPXXX,1*2\n")).unwrap();
    std::fs::write(w.path().join("pose.json"), "OLD").unwrap();
    let out = Command::new(BIN)
        .args(["localize", "--config"])
        .arg(scene().join("infraloc.toml"))
        .arg("--gps-nmea")
        .arg(&nmea)
        .arg("--out")
        .arg(w.path().join("pose.json"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.starts_with("infraloc: prior: no position: "), "{err}");
    assert!(
        err.contains(&format!("{n} lines with checksum errors")),
        "{err} (want {n} checksum errors)"
    );
    assert!(
        err.contains("0 fixes") && err.contains("fallback-wgs84"),
        "{err}"
    );
    assert!(!err.contains('{') && !err.contains('"'), "raw JSON: {err}");
    assert_eq!(
        std::fs::read_to_string(w.path().join("pose.json")).unwrap(),
        "OLD"
    );
}

#[test]
fn gps_decode_into_a_closed_pipe_exits_quietly() {
    let w = tempfile::tempdir().unwrap();
    // ~2 MB of sentences: far more than a pipe buffer holds.
    let log = std::fs::read_to_string(scene().join("gps.nmea")).unwrap();
    let big = w.path().join("big.nmea");
    std::fs::write(&big, log.repeat(2_000_000 / log.len() + 1)).unwrap();
    let mut child = Command::new(BIN)
        .args(["gps", "decode"])
        .arg(&big)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // `| head -1`: read one line, then close the pipe.
    let mut first = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut first)
        .unwrap();
    assert!(first.starts_with("{\"time\""), "{first}");
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !err.contains("Broken pipe") && !err.contains("os error 32"),
        "{err}"
    );
    assert_eq!(out.status.code(), Some(0), "{err}");
}

/// `[refine] sampling = "pv"` (the default) in the node's config runs the smooth stage: the pose file carries
/// its information over all six axes (the bound, the patches' sandwich), its covariance is the
/// information's (no jackknife ran) and covers at least what the gate judged, and the answer is
/// the one the default run polished further, not another basin.
#[test]
fn pv_sampling_from_the_config_reaches_the_pose_file() {
    let w = tempfile::tempdir().unwrap();
    let base = std::fs::read_to_string(scene().join("infraloc.toml")).unwrap();
    // The simulator writes every key, the default sampling (pv) included.
    let with_nearest = base.replace("sampling = \"pv\"", "sampling = \"nearest\"");
    assert_ne!(with_nearest, base, "{base}");
    let nearest_cfg = scene().join("nearest.toml");
    std::fs::write(&nearest_cfg, with_nearest).unwrap();
    let run = |config: &Path, out: &Path| {
        let o = Command::new(BIN)
            .args(["localize", "--config"])
            .arg(config)
            .arg("--out")
            .arg(out)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out).unwrap()).unwrap();
        v
    };
    let pv = run(&scene().join("infraloc.toml"), &w.path().join("pv.json"));
    let nearest = run(&nearest_cfg, &w.path().join("nearest.json"));
    let info = &pv["quality"]["information"];
    let axes = serde_json::json!(["x", "y", "z", "yaw", "pitch", "roll"]);
    assert_eq!(info["axes"], axes, "{pv}");
    let floats = |v: &serde_json::Value, key: &str| -> Vec<f64> {
        v[key]
            .as_array()
            .unwrap_or_else(|| panic!("{key}: {v}"))
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect()
    };
    let (bound, sandwich) = (floats(info, "sigma"), floats(info, "sandwich_sigma"));
    assert!(bound.iter().chain(&sandwich).all(|x| *x > 0.0), "{info}");
    let cov = &pv["quality"]["covariance"];
    assert_eq!(cov["source"], "information", "{cov}");
    assert_eq!(cov["axes"], axes, "{cov}");
    for (i, s) in floats(cov, "sigma").iter().enumerate() {
        assert!(
            *s >= bound[i].max(sandwich[i]) && s.is_finite(),
            "axis {i}: {cov}"
        );
    }
    assert!(nearest["quality"].get("information").is_none(), "{nearest}");
    assert_eq!(
        nearest["quality"]["covariance"]["source"], "jackknife",
        "{nearest}"
    );
    let centre = |v: &serde_json::Value| -> Vec<f64> {
        v["camera_center"]
            .as_array()
            .unwrap_or_else(|| panic!("{v}"))
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect()
    };
    let (a, b) = (centre(&pv), centre(&nearest));
    let moved = a
        .iter()
        .zip(&b)
        .map(|(x, y)| (x - y).powi(2))
        .sum::<f64>()
        .sqrt();
    assert!(moved < 0.15, "the PV stage moved the answer {moved} m");
}
