//! `infraloc study` and `infraloc plot mi-surface` through the binary, on one small simulated scene
//! (one frame, `easy`) with a small search box so that every test runs in seconds.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

const BIN: &str = env!("CARGO_BIN_EXE_infraloc");
/// A small box (11·11·5·11 cells) around each start: the commands' plumbing is under test here, not
/// the accuracy (docs/accuracy.md "Refinement" measures that).
const SEARCH: &str = "x=0.2:0.04,y=0.2:0.04,z=0.1:0.04,yaw=0.5:0.1";

/// The scene directory, simulated once per test binary (the temporary directory lives as long as
/// the process).
fn scene() -> &'static Path {
    static DIR: OnceLock<(tempfile::TempDir, PathBuf)> = OnceLock::new();
    &DIR.get_or_init(|| {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("scene");
        let out = Command::new(BIN)
            .args(["simulate", "--preset", "small", "--difficulty", "easy"])
            .args(["--seed", "5", "--frames", "1", "--out"])
            .arg(&dir)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        (tmp, dir)
    })
    .1
}

fn run(args: &[&str], extra: &[&Path]) -> Output {
    let mut c = Command::new(BIN);
    c.args(args);
    for p in extra {
        c.arg(p);
    }
    c.output().unwrap()
}

/// Assert that `out` is a successful run, showing its stderr otherwise.
fn succeeded(out: &Output) {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

fn one_line_error(out: &Output) -> String {
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr).trim().to_string();
    assert_eq!(err.lines().count(), 1, "{err}");
    err
}

#[test]
fn study_writes_every_trial_with_finite_errors() {
    let dir = scene();
    let tmp = tempfile::tempdir().unwrap();
    let (json, png) = (tmp.path().join("s.json"), tmp.path().join("s.png"));
    let out = Command::new(BIN)
        .args(["study", "--trials", "3", "--seed", "9", "--search", SEARCH])
        .args([
            "--perturb-xy",
            "0.12",
            "--perturb-z",
            "0.06",
            "--perturb-yaw",
            "0.3",
        ])
        .args(["--size", "700,600", "--scene"])
        .arg(dir)
        .arg("--json")
        .arg(&json)
        .arg("--out")
        .arg(&png)
        .output()
        .unwrap();
    succeeded(&out);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("median"), "{stdout}");
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let trials = doc["trials"].as_array().unwrap();
    assert_eq!(trials.len(), 3);
    for t in trials {
        for k in ["horizontal_m", "height_m", "yaw_deg"] {
            let v = t[k].as_f64().unwrap();
            assert!(v.is_finite() && v >= 0.0, "{k} = {v}");
        }
        // Starts stay within the requested perturbation.
        let s: Vec<f64> = serde_json::from_value(t["start"].clone()).unwrap();
        assert!(
            s[0].abs() <= 0.12 && s[1].abs() <= 0.12 && s[2].abs() <= 0.06 && s[3].abs() <= 0.3
        );
    }
    assert_eq!(doc["summary"]["trials"].as_u64(), Some(3));
    // The estimator is echoed: the default one, as no estimator flag was given.
    assert_eq!(doc["estimator"]["objective"], "mi", "{}", doc["estimator"]);
    assert_eq!(doc["estimator"]["bins-gray"], 32);
    let img = image::open(&png).unwrap();
    assert_eq!((img.width(), img.height()), (700, 600));
}

#[test]
fn study_takes_refine_s_estimator_flags() {
    let tmp = tempfile::tempdir().unwrap();
    let json = tmp.path().join("s.json");
    let png = tmp.path().join("s.png");
    succeeded(&run(
        &[
            "study",
            "--trials",
            "1",
            "--search",
            SEARCH,
            "--objective",
            "nmi",
        ],
        &[
            Path::new("--bins"),
            Path::new("16"),
            Path::new("--scene"),
            scene(),
            Path::new("--json"),
            &json,
            Path::new("--out"),
            &png,
        ],
    ));
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(doc["estimator"]["objective"], "nmi", "{}", doc["estimator"]);
    assert_eq!(doc["estimator"]["bins-reflectivity"], 16);
    for (flag, value) in [("--objective", "entropy"), ("--bins", "0")] {
        let err = one_line_error(&run(&["study", flag, value, "--scene"], &[scene()]));
        assert!(err.contains(flag), "{err}");
    }
}

#[test]
fn plot_mi_surface_writes_a_png_of_the_requested_size() {
    let dir = scene();
    let tmp = tempfile::tempdir().unwrap();
    let (png, json) = (tmp.path().join("m.png"), tmp.path().join("m.json"));
    let out = Command::new(BIN)
        .args([
            "plot",
            "mi-surface",
            "--search",
            SEARCH,
            "--size",
            "900,500",
        ])
        .arg("--scene")
        .arg(dir)
        .arg("--out")
        .arg(&png)
        .arg("--json")
        .arg(&json)
        .output()
        .unwrap();
    succeeded(&out);
    let img = image::open(&png).unwrap();
    assert_eq!((img.width(), img.height()), (900, 500));
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    // 4 profiles (x, y, z, yaw); x–y every 2nd of ±5 cells: offsets −4, −2, 0, 2, 4 steps.
    assert_eq!(doc["profiles"].as_array().unwrap().len(), 4);
    let (nx, ny) = (
        doc["grid_x"].as_array().unwrap().len(),
        doc["grid_y"].as_array().unwrap().len(),
    );
    assert_eq!((nx, ny), (5, 5));
    assert_eq!(doc["grid_mi"].as_array().unwrap().len(), nx * ny);
}

#[test]
fn missing_scene_is_a_one_line_error_naming_it() {
    let tmp = tempfile::tempdir().unwrap();
    let missing = tmp.path().join("no-such-scene");
    for args in [
        &["study", "--scene"][..],
        &["plot", "mi-surface", "--scene"][..],
    ] {
        let err = one_line_error(&run(args, &[&missing]));
        assert!(err.contains("no-such-scene"), "{err}");
    }
}

#[test]
fn zero_trials_is_a_one_line_error_naming_the_flag() {
    let err = one_line_error(&run(&["study", "--trials", "0", "--scene"], &[scene()]));
    assert!(err.contains("--trials"), "{err}");
}

#[test]
fn scene_without_frames_is_a_one_line_error_naming_them() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    std::fs::copy(scene().join("truth.json"), dir.join("truth.json")).unwrap();
    std::fs::copy(scene().join("camera.yaml"), dir.join("camera.yaml")).unwrap();
    let err = one_line_error(&run(&["study", "--scene"], &[dir]));
    assert!(err.contains("frames"), "{err}");
}
