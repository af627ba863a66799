//! `infraloc simulate` end to end through the binary: determinism and a loadable scene directory.

use infraloc::camera::load_camera;
use infraloc::config::Config;
use infraloc::map::cache::{find_tile, load_tile};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

fn simulate(out: &Path, extra: &[&str]) {
    let st = Command::new(env!("CARGO_BIN_EXE_infraloc"))
        .args(["simulate", "--out"])
        .arg(out)
        .args(["--seed", "11", "--preset", "small", "--frames", "1"])
        .args(extra)
        .status()
        .unwrap();
    assert!(st.success());
}

fn files(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    crate::common::tree_files(dir)
}

#[test]
fn two_runs_give_identical_bytes_and_the_directory_loads() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    let args = ["--difficulty", "easy", "--lens", "equidistant"];
    simulate(&a, &args);
    simulate(&b, &args);
    let (fa, fb) = (files(&a), files(&b));
    let names: Vec<_> = fa.keys().map(|p| p.display().to_string()).collect();
    for want in [
        "infraloc.toml",
        "camera.yaml",
        "frames/000.png",
        "gps.nmea",
        "truth.json",
        "tiles/sim-0011/tile.toml",
    ] {
        assert!(names.iter().any(|n| n == want), "missing {want}: {names:?}");
    }
    assert_eq!(fa.keys().collect::<Vec<_>>(), fb.keys().collect::<Vec<_>>());
    for (k, v) in &fa {
        assert!(v == &fb[k], "{} differs between runs", k.display());
    }

    // The config is valid and its paths (relative to it) reach everything.
    let cfg_path = a.join("infraloc.toml");
    let cfg = Config::load(&cfg_path).unwrap();
    cfg.validate(&cfg_path).unwrap();
    let cam = load_camera(cfg.camera.intrinsics_file.as_ref().unwrap()).unwrap();
    let truth: serde_json::Value = serde_json::from_slice(&fa[Path::new("truth.json")]).unwrap();
    // Easy: the intrinsics handed over are the true ones.
    let true_cam: infraloc::camera::Camera =
        serde_json::from_value(truth["intrinsics"].clone()).unwrap();
    assert_eq!(cam, true_cam);
    let [lat, lon] = [
        truth["gps_truth_wgs84"][0].as_f64().unwrap(),
        truth["gps_truth_wgs84"][1].as_f64().unwrap(),
    ];
    let tref = find_tile(&cfg.map.tiles, lat, lon, cfg.map.search_margin_m).unwrap();
    let tile = load_tile(&tref.dir).unwrap();
    assert_eq!(tile.reflectivity.grid.width, 1200);
    assert_eq!(truth["crs"], "EPSG:32617");
}

/// `hard`'s camera.yaml comes from the calibrator by default (a camera that loads, differs from
/// `--given-intrinsics offset`'s, states a σ); nothing else of the scene changes between the two
/// but the intrinsics' record in truth.json.
#[test]
fn calibrated_intrinsics_change_only_the_camera_file() {
    let tmp = tempfile::tempdir().unwrap();
    let (off, cal) = (tmp.path().join("off"), tmp.path().join("cal"));
    simulate(&off, &["--given-intrinsics", "offset"]);
    simulate(&cal, &[]);
    let (a, b) = (files(&off), files(&cal));
    assert_eq!(
        a.keys().collect::<Vec<_>>(),
        b.keys().collect::<Vec<_>>(),
        "the same files"
    );
    let differ: Vec<&PathBuf> = a.keys().filter(|k| a[*k] != b[*k]).collect();
    assert_eq!(
        differ,
        [Path::new("camera.yaml"), Path::new("truth.json")],
        "only the intrinsics differ"
    );
    let cam = load_camera(&cal.join("camera.yaml")).unwrap();
    assert_ne!(cam, load_camera(&off.join("camera.yaml")).unwrap());
    let text = std::fs::read_to_string(cal.join("camera.yaml")).unwrap();
    assert!(
        text.contains("sigma_focal_rel") && text.contains("sigma_principal_point_px"),
        "no stated σ: {text}"
    );
    let truth: serde_json::Value =
        serde_json::from_slice(&std::fs::read(cal.join("truth.json")).unwrap()).unwrap();
    assert_eq!(truth["settings"]["intrinsics"], "calibrated");
    let truth_off: serde_json::Value =
        serde_json::from_slice(&std::fs::read(off.join("truth.json")).unwrap()).unwrap();
    assert_eq!(truth_off["settings"]["intrinsics"], "offset");
}
