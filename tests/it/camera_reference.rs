//! Camera models against OpenCV: `infraloc project` (the real binary) must reproduce
//! `cv2.omnidir.projectPoints` / `cv2.fisheye.projectPoints` (θ < 90°) and an independent numpy
//! equidistant evaluation (θ ≥ 90°, where OpenCV's fisheye is wrong) to 1e-6 px. The references are
//! committed CSVs made by `tests/reference/make_camera_refs.py`; see docs/camera.md.

use infraloc::camera::{load_camera, to_opencv_yaml, Camera, CameraModel};
use nalgebra::Point2;
use std::path::{Path, PathBuf};
use std::process::Command;

/// Acceptance bar: agreement with the reference, pixels.
const TOL_PX: f64 = 1e-6;

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/camera");

/// (reference set name, `--camera` argument relative to DATA).
const SETS: &[(&str, &str)] = &[
    ("kitti360_image_02", "kitti360_image_02.yaml"),
    ("synthetic_skew", "synthetic_skew.yaml"),
    ("omni_calib", "omni_calib.yaml"),
    ("omni_calib_skew", "omni_calib_skew.xml"),
    ("fisheye185", "fisheye185.yaml"),
    ("kalibr_cam1", "kalibr_camchain.yaml#cam1"),
];

fn data(name: &str) -> PathBuf {
    Path::new(DATA).join(name)
}

fn project(camera: &Path, points: &Path, pose: Option<&Path>) -> std::process::Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_infraloc"));
    cmd.arg("project")
        .arg("--camera")
        .arg(camera)
        .arg("--points")
        .arg(points);
    if let Some(p) = pose {
        cmd.arg("--pose").arg(p);
    }
    cmd.output().expect("run infraloc")
}

/// Parse `u,v[,…]` lines; `None` for an empty pair.
fn parse_uv(text: &str, skip_header: bool) -> Vec<(Option<[f64; 2]>, String)> {
    text.lines()
        .skip(usize::from(skip_header))
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            assert!(f.len() >= 2, "bad line {l:?}");
            let kind = f.get(2).unwrap_or(&"").to_string();
            if f[0].is_empty() && f[1].is_empty() {
                (None, kind)
            } else {
                (Some([f[0].parse().unwrap(), f[1].parse().unwrap()]), kind)
            }
        })
        .collect()
}

/// Run one frame of one set; returns the max error per reference kind.
fn check(set: &str, camera: &str, frame: &str) -> Vec<(String, f64, usize)> {
    let cam = data(camera);
    let points = data(&format!("{set}.points_{frame}.csv"));
    let pose = data(&format!("{set}.pose.json"));
    let out = project(&cam, &points, (frame == "map").then_some(pose.as_path()));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{set} {frame}: {stderr}");
    let got = parse_uv(&String::from_utf8(out.stdout).unwrap(), false);
    let want_text = std::fs::read_to_string(data(&format!("{set}.uv_{frame}.csv"))).unwrap();
    let want = parse_uv(&want_text, true);
    assert_eq!(
        got.len(),
        want.len(),
        "{set} {frame}: one output line per point"
    );
    let mut stats: Vec<(String, f64, usize)> = Vec::new();
    for (i, ((g, _), (w, kind))) in got.iter().zip(&want).enumerate() {
        let err = match (g, w) {
            (Some(g), Some(w)) => (g[0] - w[0]).hypot(g[1] - w[1]),
            (None, None) => 0.0,
            _ => panic!(
                "{set} {frame} row {}: got {g:?}, reference ({kind}) {w:?}",
                i + 2
            ),
        };
        assert!(
            err <= TOL_PX,
            "{set} {frame} row {}: |Δ| = {err:e} px (got {g:?}, {kind} {w:?})",
            i + 2
        );
        match stats.iter_mut().find(|s| &s.0 == kind) {
            Some(s) => {
                s.1 = s.1.max(err);
                s.2 += 1
            }
            None => stats.push((kind.clone(), err, 1)),
        }
    }
    stats
}

#[test]
fn project_matches_opencv_camera_and_map_frames() {
    for (set, camera) in SETS {
        for frame in ["cam", "map"] {
            let stats = check(set, camera, frame);
            for (kind, max, n) in &stats {
                eprintln!("{set:18} {frame}: {n:4} points vs {kind:6} max |Δ| = {max:.3e} px");
            }
            // Every Mei set is checked against OpenCV on most points, every fisheye set against
            // both OpenCV (θ < 90°) and numpy (θ ≥ 90°).
            let count = |k: &str| stats.iter().find(|s| s.0 == k).map_or(0, |s| s.2);
            assert!(
                count("opencv") > 200,
                "{set} {frame}: too few OpenCV references"
            );
            if set.starts_with("fisheye") || set.starts_with("kalibr") {
                assert!(
                    count("numpy") > 100,
                    "{set} {frame}: too few θ ≥ 90° references"
                );
            }
        }
    }
}

/// Pixel → ray → pixel over a grid covering the whole sensor; every pixel the model can unproject
/// must come back within the tolerance, and the valid part must be a real share of the image.
#[test]
fn round_trip_over_the_valid_image() {
    const GRID: u32 = 150;
    for (set, camera) in SETS {
        let cam = load_camera(&data(camera)).unwrap();
        let (w, h) = (cam.width() as f64, cam.height() as f64);
        let (mut n, mut max) = (0usize, 0f64);
        for j in 0..=GRID {
            for i in 0..=GRID {
                // Pixel centres span −0.5 … size − 0.5.
                let px = Point2::new(
                    -0.5 + w * i as f64 / GRID as f64,
                    -0.5 + h * j as f64 / GRID as f64,
                );
                if !cam.is_valid_pixel(&px) {
                    continue;
                }
                let ray = cam.unproject(&px).unwrap();
                let back = cam.project(&ray).unwrap();
                max = max.max((back - px).norm());
                n += 1;
            }
        }
        let share = n as f64 / ((GRID + 1) * (GRID + 1)) as f64;
        eprintln!(
            "{set:18} round trip: {n} pixels ({:.0}%), max |Δ| = {max:.3e} px",
            share * 100.0
        );
        assert!(max <= TOL_PX, "{set}: round trip {max:e} px");
        assert!(
            share > 0.25,
            "{set}: only {:.1}% of the image valid",
            share * 100.0
        );
    }
}

/// `to_opencv_yaml` output is read by OpenCV's own FileStorage, value for value, and by us.
#[test]
fn opencv_reads_our_yaml() {
    let dir = tempfile::tempdir().unwrap();
    for (set, camera) in SETS {
        let cam = load_camera(&data(camera)).unwrap();
        let path = dir.path().join(format!("{set}.yaml"));
        std::fs::write(&path, to_opencv_yaml(&cam)).unwrap();
        assert_eq!(
            load_camera(&path).unwrap(),
            cam,
            "{set}: our own round trip"
        );
        let script = r#"
import sys, cv2
fs = cv2.FileStorage(sys.argv[1], cv2.FILE_STORAGE_READ)
K = fs.getNode("camera_matrix").mat(); D = fs.getNode("distortion_coefficients").mat().ravel()
xi = fs.getNode("xi")
vals = [fs.getNode("image_width").real(), fs.getNode("image_height").real(),
        K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2], *D]
if not xi.empty(): vals.append(xi.mat()[0, 0])
print(fs.getNode("model").string(), *[repr(float(v)) for v in vals])
"#;
        let out = Command::new("python3")
            .arg("-c")
            .arg(script)
            .arg(&path)
            .output()
            .expect("python3 (with cv2) is needed: see .ci/setup");
        assert!(
            out.status.success(),
            "cv2 could not read {set}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let text = String::from_utf8(out.stdout).unwrap();
        let mut f = text.split_whitespace();
        let model = f.next().unwrap().to_string();
        let v: Vec<f64> = f.map(|s| s.parse().unwrap()).collect();
        let want: Vec<f64> = match &cam {
            Camera::Mei(m) => vec![
                m.width as f64,
                m.height as f64,
                m.fx,
                m.skew,
                m.cx,
                m.fy,
                m.cy,
                m.k1,
                m.k2,
                m.p1,
                m.p2,
                m.xi,
            ],
            Camera::Equidistant(e) => vec![
                e.width as f64,
                e.height as f64,
                e.fx,
                e.alpha * e.fx,
                e.cx,
                e.fy,
                e.cy,
                e.k1,
                e.k2,
                e.k3,
                e.k4,
            ],
        };
        let want_model = if matches!(cam, Camera::Mei(_)) {
            "mei"
        } else {
            "equidistant"
        };
        assert_eq!(model, want_model, "{set}");
        assert_eq!(v, want, "{set}: cv2 read different values");
    }
}

#[test]
fn errors_name_file_key_and_line() {
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(data("omni_calib.yaml")).unwrap();
    let cam = dir.path().join("nosize.yaml");
    std::fs::write(&cam, text.replace("image_width: 1280\n", "")).unwrap();
    let out = project(&cam, &data("omni_calib.points_cam.csv"), None);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        err.contains("nosize.yaml: missing key image_width"),
        "{err}"
    );
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");

    // A real OpenCV XML file that is not an intrinsics file (the omnidir calibration input).
    let calib_data = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../shared/data/omnidir/omni_calib_data.xml"
    );
    let out = project(
        Path::new(calib_data),
        &data("omni_calib.points_cam.csv"),
        None,
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("omni_calib_data.xml: missing key camera_matrix"),
        "{err}"
    );

    let pts = dir.path().join("pts.csv");
    std::fs::write(&pts, "x,y,z\n1,2,3\n1,2,zz\n").unwrap();
    let out = project(&data("omni_calib.yaml"), &pts, None);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("pts.csv: line 3: z is not a number"), "{err}");
    assert!(out.stdout.is_empty(), "no partial output on bad input");
}
