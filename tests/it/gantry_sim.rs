//! `infraloc simulate --preset gantry` through the binary: determinism, the LiDAR sweep's ring
//! structure, that the perspective truth lays the sweep onto the rendered image, and that
//! `refine` and `study` run on it (their accuracy is docs/accuracy.md's business, not this
//! file's).

use infraloc::camera::{load_camera, CameraModel};
use infraloc::points_io::read_points;
use infraloc::posefile::read_pose;
use nalgebra::{Point3, Vector3};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

const BIN: &str = env!("CARGO_BIN_EXE_infraloc");
/// A small box around the start: the plumbing is under test here, not the accuracy.
const SEARCH: &str = "x=0.2:0.05,y=0.2:0.05,z=0.1:0.05,yaw=0.5:0.1";

fn simulate(out: &Path, seed: &str) -> Output {
    Command::new(BIN)
        .args(["simulate", "--preset", "gantry", "--difficulty", "easy"])
        .args(["--seed", seed, "--frames", "1", "--out"])
        .arg(out)
        .output()
        .unwrap()
}

/// One gantry scene per test binary (the temporary directory lives as long as the process).
fn scene() -> &'static Path {
    static DIR: OnceLock<(tempfile::TempDir, PathBuf)> = OnceLock::new();
    &DIR.get_or_init(|| {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("scene");
        let out = simulate(&dir, "3");
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        (tmp, dir)
    })
    .1
}

fn run(args: &[&str], dir: &Path) -> Output {
    Command::new(BIN)
        .args(args)
        .current_dir(dir)
        .output()
        .unwrap()
}

#[test]
fn same_seed_same_bytes() {
    let tmp = tempfile::tempdir().unwrap();
    let again = tmp.path().join("again");
    assert!(simulate(&again, "3").status.success());
    let (a, b) = (
        crate::common::tree_files(scene()),
        crate::common::tree_files(&again),
    );
    let names: Vec<String> = a.keys().map(|p| p.display().to_string()).collect();
    for want in [
        "perspective/camera.yaml",
        "perspective/frames/000.png",
        "perspective/truth.json",
        "perspective/truth_lidar.json",
        "perspective/start.json",
        "perspective/pairs.tsv",
        "lidar/000.pcd",
        "lidar/lidar.json",
        "frames/000.png",
        "truth.json",
    ] {
        assert!(names.iter().any(|n| n == want), "missing {want}: {names:?}");
    }
    // The study's outputs may have been written into the shared scene meanwhile (the other tests
    // write nothing else there).
    let keep = |f: &(&PathBuf, &Vec<u8>)| !f.0.to_string_lossy().starts_with("study");
    let a: Vec<_> = a.iter().filter(keep).collect();
    let b: Vec<_> = b.iter().filter(keep).collect();
    assert_eq!(a.len(), b.len());
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(x.0, y.0);
        assert!(x.1 == y.1, "{} differs between runs", x.0.display());
    }
}

/// The sweep's rings, read from the PCD's `ring` column.
fn rings(pcd: &Path) -> std::collections::BTreeSet<u32> {
    let text = std::fs::read_to_string(pcd).unwrap();
    let fields: Vec<&str> = text
        .lines()
        .find_map(|l| l.strip_prefix("FIELDS "))
        .unwrap()
        .split_whitespace()
        .collect();
    let k = fields.iter().position(|f| *f == "ring").unwrap();
    let body = text.split("DATA ascii\n").nth(1).unwrap();
    body.lines()
        .map(|l| l.split_whitespace().nth(k).unwrap().parse().unwrap())
        .collect()
}

/// Mutual information (nats, 32 equal-count bins a side) of the points' reflectivity with the
/// image gray at their nearest pixel, for the camera at `pose` (LiDAR frame), and how many points
/// project into the image. Written here from scratch, independent of the estimator's code.
fn mutual_information(
    cam: &infraloc::camera::Camera,
    gray: &image::GrayImage,
    pts: &[infraloc::map::GroundPoint],
    pose: &infraloc::pose::CamFromMap,
) -> (f64, usize) {
    let (mut refl, mut grey) = (Vec::new(), Vec::new());
    for p in pts {
        let q = pose.transform(&Point3::new(p.x, p.y, p.z));
        if q.z <= 0.0 {
            continue;
        }
        let Ok(px) = cam.project(&q.coords) else {
            continue;
        };
        let (u, v) = (px.x.round(), px.y.round());
        if u < 0.0 || v < 0.0 || u >= gray.width() as f64 || v >= gray.height() as f64 {
            continue;
        }
        refl.push(p.reflectivity as f64);
        grey.push(gray.get_pixel(u as u32, v as u32).0[0] as f64);
    }
    const BINS: usize = 32;
    let n = refl.len();
    // Equal-count bins: each value's rank (ties broken by position) scaled to 0..BINS.
    let bins = |x: &[f64]| {
        let mut idx: Vec<usize> = (0..x.len()).collect();
        idx.sort_by(|&a, &b| x[a].total_cmp(&x[b]));
        let mut b = vec![0usize; x.len()];
        for (rank, &i) in idx.iter().enumerate() {
            b[i] = rank * BINS / x.len();
        }
        b
    };
    let (br, bg) = (bins(&refl), bins(&grey));
    let mut joint = vec![0f64; BINS * BINS];
    for (r, g) in br.iter().zip(&bg) {
        joint[r * BINS + g] += 1.0 / n as f64;
    }
    let pr: Vec<f64> = (0..BINS)
        .map(|r| joint[r * BINS..(r + 1) * BINS].iter().sum())
        .collect();
    let pg: Vec<f64> = (0..BINS)
        .map(|g| (0..BINS).map(|r| joint[r * BINS + g]).sum())
        .collect();
    let mut mi = 0.0;
    for r in 0..BINS {
        for g in 0..BINS {
            let p = joint[r * BINS + g];
            if p > 0.0 {
                mi += p * (p / (pr[r] * pg[g])).ln();
            }
        }
    }
    (mi, n)
}

#[test]
fn sweep_has_64_rings_and_lies_on_the_image_at_the_truth() {
    let dir = scene();
    let pcd = dir.join("lidar/000.pcd");
    assert_eq!(rings(&pcd), (0..64).collect());
    let cam = load_camera(&dir.join("perspective/camera.yaml")).unwrap();
    let gray = image::open(dir.join("perspective/frames/000.png"))
        .unwrap()
        .to_luma8();
    let pts = read_points(&pcd).unwrap();
    let truth = read_pose(&dir.join("perspective/truth_lidar.json"))
        .unwrap()
        .pose;
    let (mi_true, in_view) = mutual_information(&cam, &gray, &pts, &truth);
    assert!(
        (4_000..=20_000).contains(&in_view),
        "{in_view} points in view"
    );
    // Half a metre sideways (along the image's horizontal axis), either way: the markings no
    // longer line up. (Along the view the gantry's objective is flat, as on the real one.)
    let mut side = truth.rotation.inverse() * Vector3::x();
    side.z = 0.0;
    let side = side.normalize() * 0.5;
    for dc in [side, -side] {
        let (mi_off, _) = mutual_information(&cam, &gray, &pts, &truth.perturbed(&dc, 0.0));
        assert!(
            mi_true > 0.1 && mi_off < 0.8 * mi_true,
            "MI {mi_true:.3} nats at the truth, {mi_off:.3} at 0.5 m off"
        );
    }
    // truth.json records the same count in view.
    let t: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("truth.json")).unwrap()).unwrap();
    let g = &t["acquisition"]["gantry"];
    assert_eq!(g["sweep_points_in_view"].as_u64(), Some(in_view as u64));
    assert_eq!(g["sweep_points"][0].as_u64(), Some(pts.len() as u64));
    // The sun is low.
    assert!(
        t["acquisition"]["camera_sun_az_el_deg"][1]
            .as_f64()
            .unwrap()
            <= 25.0
    );
}

#[test]
fn refine_runs_and_answers_or_names_its_refusal() {
    let p = scene().join("perspective");
    // The report goes outside the shared scene, which `same_seed_same_bytes` compares.
    let tmp = tempfile::tempdir().unwrap();
    let report_path = tmp.path().join("report.json");
    let out = run(
        &[
            "refine",
            "--camera",
            "camera.yaml",
            "--image",
            "frames/000.png",
            "--points",
            "../lidar/000.pcd",
            "--init",
            "start.json",
            "--search",
            SEARCH,
            "--report",
            report_path.to_str().unwrap(),
        ],
        &p,
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    // Served (0 precise, 5 coarse) or refused (1), one line naming why.
    if matches!(out.status.code(), Some(0 | 5)) {
        assert!(String::from_utf8_lossy(&out.stdout).contains("mi: moved"));
    } else {
        assert!(stderr.contains("result refused: "), "{stderr}");
        assert!(stderr.lines().count() == 1, "{stderr}");
    }
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&report_path).unwrap()).unwrap();
    assert!(
        report["quality"]["points"].as_u64().unwrap() > 1000,
        "{report}"
    );
}

#[test]
fn study_runs_on_the_perspective_camera() {
    let dir = scene();
    let json = dir.join("study-perspective.json");
    let out = Command::new(BIN)
        .args(["study", "--sensor", "perspective", "--trials", "2"])
        .args([
            "--search",
            SEARCH,
            "--perturb-xy",
            "0.1",
            "--perturb-z",
            "0.05",
        ])
        .args(["--perturb-yaw", "0.2", "--size", "400,300", "--scene"])
        .arg(dir)
        .arg("--json")
        .arg(&json)
        .arg("--out")
        .arg(dir.join("study-perspective.png"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let doc: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    assert_eq!(doc["sensor"], "perspective");
    assert_eq!(doc["trials"].as_array().unwrap().len(), 2);
    // A scene of another preset has no perspective/ directory: one line naming what is missing.
    let tmp = tempfile::tempdir().unwrap();
    let small = tmp.path();
    let out = Command::new(BIN)
        .args([
            "study",
            "--sensor",
            "perspective",
            "--trials",
            "1",
            "--scene",
        ])
        .arg(small)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("perspective") && err.contains("--preset gantry"),
        "{err}"
    );
}
