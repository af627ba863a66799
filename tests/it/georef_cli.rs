//! `infraloc georef` (the real binary) on a tilted ground patch against an independent reference:
//! the pixel's ray from `cv2.omnidir.undistortPoints` and numpy, met with the analytic plane the
//! tile's height layer samples. Plus its answers to bad input: malformed CSV, NaN pixels, an
//! empty batch, a missing pose or tile (docs/georef.md).

use infraloc::camera::{to_opencv_yaml, Camera, CameraModel, Mei};
use infraloc::map::{Crs, GeoGrid, Raster, Tile};
use infraloc::pose::CamFromMap;
use infraloc::posefile::{PoseFile, PoseQuality};
use nalgebra::{Point3, Vector3};
use std::path::PathBuf;
use std::process::{Command, Output, Stdio};

/// Acceptance bar: agreement with the reference, metres.
const TOL_M: f64 = 1e-3;

const CRS: Crs = Crs::Epsg(32632);
const E0: f64 = 690_000.0;
const N0: f64 = 5_330_000.0;

/// The ground: a plane tilted 4 % east and −2.5 % north, 500 m up.
fn plane(x: f64, y: f64) -> f64 {
    500.0 + 0.04 * (x - E0) - 0.025 * (y - N0)
}
const SLOPE: [f64; 2] = [0.04, -0.025];

fn lens() -> Mei {
    Mei {
        width: 1280,
        height: 960,
        fx: 420.0,
        fy: 421.5,
        cx: 641.2,
        cy: 478.9,
        skew: 0.0,
        xi: 1.1,
        k1: -0.02,
        k2: 0.008,
        p1: 3e-4,
        p2: -2e-4,
        fov_deg: Some(185.0),
    }
}

fn pose() -> CamFromMap {
    CamFromMap::from_center_ypr(
        &Point3::new(E0 + 0.37, N0 - 0.81, 506.4),
        33f64.to_radians(),
        3f64.to_radians(),
        -2f64.to_radians(),
    )
}

/// A scene directory: tile cache, camera YAML, pose file (with a covariance).
struct Scene {
    _dir: tempfile::TempDir,
    tiles: PathBuf,
    camera: PathBuf,
    pose: PathBuf,
}

fn scene() -> Scene {
    let dir = tempfile::tempdir().unwrap();
    let g = GeoGrid {
        crs: CRS,
        x0: E0 - 40.0,
        y0: N0 + 40.0,
        res: 0.1,
        width: 800,
        height: 800,
    };
    let mut h = Raster::filled(g, 0.0f32, Some(-9999.0));
    for row in 0..g.height {
        for col in 0..g.width {
            let x = g.x0 + (col as f64 + 0.5) * g.res;
            let y = g.y0 - (row as f64 + 0.5) * g.res;
            h.data[row * g.width + col] = plane(x, y) as f32;
        }
    }
    let tile = Tile {
        id: "patch".into(),
        satellite: Some(Raster::filled(g, [90, 90, 90], None)),
        reflectivity: Raster::filled(g, 100u8, Some(0)),
        height: h,
        control_points: vec![],
    };
    let tiles = dir.path().join("tiles");
    infraloc::map::cache::write_tile(&tiles, &tile).unwrap();
    let camera = dir.path().join("camera.yaml");
    std::fs::write(&camera, to_opencv_yaml(&Camera::Mei(lens()))).unwrap();
    let mut pf = PoseFile::new(&pose(), CRS, "patch", "2026-11-27T00:00:00Z".into());
    pf.quality = PoseQuality::from_value(serde_json::json!({
        "sigma": {"x": 0.01, "y": 0.012, "z": 0.02, "yaw": 0.02, "pitch": 0.01, "roll": 0.01},
        "covariance": {
            "axes": ["x", "y", "z", "yaw", "pitch", "roll"],
            "units": ["m", "m", "m", "deg", "deg", "deg"],
            "matrix": diag(&[1e-4, 1.44e-4, 4e-4, 4e-4, 1e-4, 1e-4]),
        }
    }));
    let pose = dir.path().join("pose.json");
    std::fs::write(&pose, pf.to_json()).unwrap();
    Scene {
        _dir: dir,
        tiles,
        camera,
        pose,
    }
}

fn diag(v: &[f64]) -> Vec<Vec<f64>> {
    (0..v.len())
        .map(|i| {
            (0..v.len())
                .map(|j| if i == j { v[i] } else { 0.0 })
                .collect()
        })
        .collect()
}

fn georef(s: &Scene, pixels: &str, extra: &[&str]) -> Output {
    georef_with(
        &[
            "--pose",
            s.pose.to_str().unwrap(),
            "--camera",
            s.camera.to_str().unwrap(),
            "--tiles",
            s.tiles.to_str().unwrap(),
        ],
        pixels,
        extra,
    )
}

fn georef_with(args: &[&str], pixels: &str, extra: &[&str]) -> Output {
    use std::io::Write;
    let mut child = Command::new(env!("CARGO_BIN_EXE_infraloc"))
        .arg("georef")
        .args(args)
        .args(extra)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run infraloc");
    child
        .stdin
        .take()
        .unwrap()
        .write_all(pixels.as_bytes())
        .unwrap();
    child.wait_with_output().unwrap()
}

/// The reference: numpy + cv2.omnidir. Reads the camera YAML with cv2.FileStorage and the pose
/// file's R and t; prints `E N h` per pixel (θ < 90° only: undistortPoints' z = 1 plane).
const REFERENCE: &str = r#"
import sys, json, numpy as np, cv2
fs = cv2.FileStorage(sys.argv[1], cv2.FILE_STORAGE_READ)
K = fs.getNode("camera_matrix").mat(); D = fs.getNode("distortion_coefficients").mat().reshape(1, 4)
xi = np.array([[fs.getNode("xi").real() if fs.getNode("xi").isReal() else fs.getNode("xi").mat()[0, 0]]])
p = json.load(open(sys.argv[2]))
R = np.array(p["rotation_cam_from_map"]); t = np.array(p["translation_cam_from_map"])
c = -R.T @ t
e0, n0, h0, sx, sy = map(float, sys.argv[3:8])
for line in sys.stdin:
    u, v = map(float, line.split(","))
    und = cv2.omnidir.undistortPoints(np.array([[[u, v]]], np.float64), K, D, xi, np.eye(3))
    d = R.T @ np.array([und[0, 0, 0], und[0, 0, 1], 1.0])
    # c + s d on z = h0 + sx (x - e0) + sy (y - n0)
    g = lambda q: q[2] - (h0 + sx * (q[0] - e0) + sy * (q[1] - n0))
    s = -g(c) / (d[2] - sx * d[0] - sy * d[1])
    q = c + s * d
    # float(): numpy 2 writes a numpy scalar's repr as np.float64(…).
    print(repr(float(q[0])), repr(float(q[1])), repr(float(q[2])))
"#;

fn reference(s: &Scene, pixels: &[[f64; 2]]) -> Vec<[f64; 3]> {
    use std::io::Write;
    let mut child = Command::new("python3")
        .arg("-c")
        .arg(REFERENCE)
        .arg(&s.camera)
        .arg(&s.pose)
        .args([E0, N0, 500.0, SLOPE[0], SLOPE[1]].map(|v| v.to_string()))
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("python3 (with cv2) is needed: see .ci/setup");
    let text: String = pixels
        .iter()
        .map(|p| format!("{},{}\n", p[0], p[1]))
        .collect();
    child
        .stdin
        .take()
        .unwrap()
        .write_all(text.as_bytes())
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "reference: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|l| {
            let v: Vec<f64> = l.split(' ').map(|x| x.parse().unwrap()).collect();
            [v[0], v[1], v[2]]
        })
        .collect()
}

/// One CSV row of `georef`'s output: status, [e, n, h], [σmaj, σmin, angle].
type Row = (String, Option<[f64; 3]>, Option<[f64; 3]>);

/// CSV rows of `georef`'s output.
fn rows(out: &Output) -> Vec<Row> {
    assert!(
        out.status.success(),
        "georef: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout.clone()).unwrap();
    let mut lines = text.lines();
    assert_eq!(
        lines.next(),
        Some("u,v,status,e,n,h,lat,lon,sigma_major_m,sigma_minor_m,angle_deg")
    );
    lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            assert_eq!(f.len(), 11, "{l}");
            let nums = |a: usize| -> Option<[f64; 3]> {
                Some([
                    f[a].parse().ok()?,
                    f[a + 1].parse().ok()?,
                    f[a + 2].parse().ok()?,
                ])
            };
            (f[2].to_string(), nums(3), nums(8))
        })
        .collect()
}

#[test]
fn georef_agrees_with_numpy_and_cv2_omnidir_on_a_tilted_patch() {
    let s = scene();
    let cam = lens();
    // Pixels over the image whose rays are within 80° of the optical axis (undistortPoints'
    // z = 1 plane) and reach the ground within the tile.
    let mut pixels = Vec::new();
    for v in (20..960).step_by(31) {
        for u in (15..1280).step_by(37) {
            let px = [u as f64 + 0.3, v as f64 + 0.7];
            let ok = cam
                .unproject(&nalgebra::Point2::new(px[0], px[1]))
                .is_ok_and(|b| b.z > 80f64.to_radians().cos());
            if ok {
                pixels.push(px);
            }
        }
    }
    let text: String = pixels
        .iter()
        .map(|p| format!("{},{}\n", p[0], p[1]))
        .collect();
    let got = rows(&georef(&s, &text, &[]));
    let want = reference(&s, &pixels);
    assert_eq!(got.len(), pixels.len());
    let mut worst: f64 = 0.0;
    let mut n = 0;
    for ((px, (status, enh, _)), w) in pixels.iter().zip(&got).zip(&want) {
        // Rays that leave the 80 m tile first have no height under them.
        let far = (w[0] - (E0 + 0.37)).hypot(w[1] - (N0 - 0.81)) > 39.0;
        if far {
            assert!(status == "no_height" || status == "ok", "{px:?}: {status}");
            continue;
        }
        assert_eq!(status, "ok", "pixel {px:?}");
        let g = enh.unwrap();
        // The CSV has 0.1 mm decimals.
        let err = ((g[0] - w[0]).powi(2) + (g[1] - w[1]).powi(2) + (g[2] - w[2]).powi(2)).sqrt();
        worst = worst.max(err);
        n += 1;
    }
    assert!(n >= 200, "{n} pixels compared");
    assert!(worst <= TOL_M, "largest difference {worst} m");
    eprintln!("{n} pixels, largest difference {:.3} mm", worst * 1e3);
}

#[test]
fn georef_on_the_patch_has_the_pose_covariance_in_its_ellipses() {
    let s = scene();
    let cam = lens();
    let nadir = cam
        .project(&(pose().rotation * Vector3::new(0.0, 0.0, -1.0)))
        .unwrap();
    let side = cam
        .project(&(pose().rotation * Vector3::new(10.0, 0.0, -6.4)))
        .unwrap();
    let text = format!("u,v\n{},{}\n{},{}\n", nadir.x, nadir.y, side.x, side.y);
    let r = rows(&georef(&s, &text, &[]));
    let (a, b) = (r[0].2.unwrap(), r[1].2.unwrap());
    // Under the camera: about the centre's σ (1.0, 1.2 cm) with the tilts' 6.4 m lever
    // (0.01° ≈ 0.11 cm); 10 m out the yaw's 0.02° adds ~0.35 cm across the ray.
    assert!(a[0] > 0.011 && a[0] < 0.0135, "{a:?}");
    assert!(b[0] > a[0], "{b:?} against {a:?}");
    // Pixel noise widens them.
    let r2 = rows(&georef(&s, &text, &["--sigma-px", "1"]));
    assert!(r2[1].2.unwrap()[0] > b[0]);
}

#[test]
fn bad_input_gets_a_status_or_one_line() {
    let s = scene();
    // NaN and off-image pixels are statuses; the batch goes on.
    let r = rows(&georef(&s, "u,v\nnan,3\n-5,10\n640,480\n", &[]));
    let st: Vec<&str> = r.iter().map(|x| x.0.as_str()).collect();
    assert_eq!(st, ["non_finite", "outside_image", "ok"]);
    // An empty batch is an empty answer.
    assert_eq!(rows(&georef(&s, "", &[])).len(), 0);
    // Malformed CSV: one line naming stdin and the line.
    let one_line = |o: &Output, want: &str| {
        assert_eq!(o.status.code(), Some(1));
        let e = String::from_utf8_lossy(&o.stderr);
        assert_eq!(e.lines().count(), 1, "{e}");
        assert!(e.contains(want), "{e}");
        assert!(o.stdout.is_empty());
    };
    one_line(
        &georef(&s, "1,2\n3,x\n", &[]),
        "<stdin>: line 2: v is not a number",
    );
    // A missing pose, a missing tile.
    let missing = s.tiles.join("nope.json");
    let o = georef_with(
        &[
            "--pose",
            missing.to_str().unwrap(),
            "--camera",
            s.camera.to_str().unwrap(),
            "--tiles",
            s.tiles.to_str().unwrap(),
        ],
        "1,2\n",
        &[],
    );
    one_line(&o, "nope.json");
    let empty = tempfile::tempdir().unwrap();
    let o = georef_with(
        &[
            "--pose",
            s.pose.to_str().unwrap(),
            "--camera",
            s.camera.to_str().unwrap(),
            "--tiles",
            empty.path().to_str().unwrap(),
        ],
        "1,2\n",
        &[],
    );
    one_line(&o, "patch");
    // JSON output names the pose it used.
    let o = georef(&s, "640,480\n", &["--format", "json"]);
    assert!(o.status.success());
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["pose"]["timestamp_utc"], "2026-11-27T00:00:00Z");
    assert_eq!(v["points"][0]["status"], "ok");
    assert!(v["points"][0]["lat"].as_f64().unwrap() > 48.0);
    // … and the surface: the smoothing, and the height σ the covariance carries (the plane's
    // samples have no noise; a given σ is used as given).
    assert_eq!(v["surface"]["smoothing_m"], 0.15);
    assert!(
        v["surface"]["height_sigma_m"].as_f64().unwrap() < 1e-4,
        "{v}"
    );
    let o = georef(
        &s,
        "640,480\n",
        &[
            "--format",
            "json",
            "--height-sigma",
            "0.05",
            "--height-smoothing",
            "0",
        ],
    );
    let w: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(w["surface"]["smoothing_m"], 0.0);
    assert_eq!(w["surface"]["height_sigma_m"], 0.05);
    let major = |v: &serde_json::Value| v["points"][0]["sigma_major_m"].as_f64().unwrap();
    assert!(major(&w) > major(&v), "{w}");
    // Out-of-range height settings are one line each.
    one_line(
        &georef(&s, "1,2\n", &["--height-sigma=-1"]),
        "--height-sigma -1: must be a finite number ≥ 0",
    );
    one_line(
        &georef(&s, "1,2\n", &["--height-smoothing", "2"]),
        "--height-smoothing 2: must be in [0, 1] metres",
    );
}
