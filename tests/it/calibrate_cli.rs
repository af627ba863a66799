//! `infraloc calibrate` on opencv_contrib's real omnidir corner detections (`omni_calib_data.xml`),
//! against `cv2.omnidir.calibrate` run live on the same data: our RMS — recomputed by OpenCV's own
//! `projectPoints` from the YAML we wrote and the poses in our report — is no worse than OpenCV's,
//! and the two fits map rays to the same pixels. Plus the bad-input lines.

use infraloc::calib::corners::{parse_corners, to_corners_yaml};
use infraloc::camera::{load_camera, Camera, CameraModel};
use nalgebra::Vector3;
use std::path::{Path, PathBuf};
use std::process::Command;

const OMNI: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../shared/data/omnidir/omni_calib_data.xml"
);

fn calibrate(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_infraloc"))
        .arg("calibrate")
        .args(args)
        .output()
        .expect("run infraloc")
}

fn python(script: &str, args: &[&Path]) -> String {
    let out = Command::new("python3")
        .arg("-c")
        .arg(script)
        .args(args)
        .output()
        .expect("python3 (with cv2) is needed: see .ci/setup");
    assert!(
        out.status.success(),
        "python: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// OpenCV's calibration of the same file: rms, then fx skew cx fy cy k1 k2 p1 p2 xi.
const CV_CALIBRATE: &str = r#"
import sys, cv2, numpy as np
fs = cv2.FileStorage(sys.argv[1], cv2.FILE_STORAGE_READ)
on, ip = fs.getNode("objectPoints"), fs.getNode("imagePoints")
obj = [on.at(i).mat().reshape(-1, 1, 3).astype(np.float64) for i in range(on.size())]
img = [ip.at(i).mat().reshape(-1, 1, 2).astype(np.float64) for i in range(ip.size())]
crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-8)
rms, K, xi, D, _, _, idx = cv2.omnidir.calibrate(obj, img, (1280, 960), None, None, None, 0, crit)
D = D.ravel()
print(len(idx.ravel()), *[repr(float(v)) for v in
      [rms, K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2], D[0], D[1], D[2], D[3], xi.ravel()[0]]])
"#;

/// RMS of our fit recomputed by OpenCV: our YAML read with cv2.FileStorage, our poses from the
/// report, cv2.omnidir.projectPoints.
const CV_RMS_OF_OURS: &str = r#"
import sys, json, cv2, numpy as np
data = cv2.FileStorage(sys.argv[1], cv2.FILE_STORAGE_READ)
on, ip = data.getNode("objectPoints"), data.getNode("imagePoints")
cam = cv2.FileStorage(sys.argv[2], cv2.FILE_STORAGE_READ)
K = cam.getNode("camera_matrix").mat()
D = cam.getNode("distortion_coefficients").mat().reshape(1, 4)
xi = float(cam.getNode("xi").mat().ravel()[0])
rep = json.load(open(sys.argv[3]))
ss, n = 0.0, 0
for i, v in enumerate(rep["views"]):
    if not v["used"]:
        continue
    obj = on.at(i).mat().reshape(-1, 1, 3).astype(np.float64)
    img = ip.at(i).mat().reshape(-1, 2).astype(np.float64)
    p, _ = cv2.omnidir.projectPoints(obj, np.array(v["rvec"]), np.array(v["tvec"]), K, xi, D)
    e = p.reshape(-1, 2) - img
    ss += float((e ** 2).sum()); n += len(img)
print(repr((ss / n) ** 0.5), repr(cam.getNode("rms").real()))
"#;

fn nums(s: &str) -> Vec<f64> {
    s.split_whitespace().map(|t| t.parse().unwrap()).collect()
}

/// Largest pixel distance between two cameras over the rays with θ ≤ `max_deg`.
fn mapping_max(a: &Camera, b: &Camera, max_deg: f64) -> f64 {
    let mut max = 0.0f64;
    for i in 0..=60 {
        let th = (max_deg * i as f64 / 60.0).to_radians();
        for j in 0..72 {
            let az = (j as f64 * 5.0).to_radians();
            let ray = Vector3::new(th.sin() * az.cos(), th.sin() * az.sin(), th.cos());
            let (pa, pb) = (a.project(&ray).unwrap(), b.project(&ray).unwrap());
            max = max.max((pa - pb).norm());
        }
    }
    max
}

#[test]
fn omni_calib_data_matches_opencv() {
    let dir = tempfile::tempdir().unwrap();
    let (yaml, report, png) = (
        dir.path().join("cam.yaml"),
        dir.path().join("report.json"),
        dir.path().join("coverage.png"),
    );
    let out = calibrate(&[
        "--model",
        "mei",
        "--corners",
        OMNI,
        "--out",
        yaml.to_str().unwrap(),
        "--report",
        report.to_str().unwrap(),
        "--coverage",
        png.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let ours = load_camera(&yaml).expect("the importer reads the calibrator's YAML");
    let Camera::Mei(m) = &ours else {
        panic!("not mei")
    };
    let rep: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    let views = rep["views"].as_array().unwrap();
    assert_eq!(views.len(), 15);
    assert!(
        views.iter().all(|v| v["used"] == true),
        "no view of the real data is an outlier"
    );
    assert_eq!(rep["corners_used"], 15 * 54);

    let cv = nums(&python(CV_CALIBRATE, &[Path::new(OMNI)]));
    assert_eq!(cv[0], 15.0, "OpenCV kept all views too");
    let cv_rms = cv[1];
    let mine = nums(&python(CV_RMS_OF_OURS, &[Path::new(OMNI), &yaml, &report]));
    let (recomputed, written) = (mine[0], mine[1]);
    eprintln!("RMS: ours {recomputed:.6} (file {written:.6}), OpenCV {cv_rms:.6}");
    assert!(
        (recomputed - written).abs() < 1e-6,
        "{recomputed} vs {written}"
    );
    assert!(
        recomputed <= cv_rms + 1e-6,
        "ours {recomputed} > OpenCV {cv_rms}"
    );

    // Parameters: the same minimum as OpenCV's.
    let want = &cv[2..];
    let got = [m.fx, m.skew, m.cx, m.fy, m.cy, m.k1, m.k2, m.p1, m.p2, m.xi];
    let names = ["fx", "skew", "cx", "fy", "cy", "k1", "k2", "p1", "p2", "xi"];
    let tol = [2.0, 0.5, 1.0, 2.0, 1.0, 0.01, 0.01, 2e-3, 2e-3, 0.01];
    for i in 0..10 {
        eprintln!(
            "{:>5}: ours {:>12.6} OpenCV {:>12.6}",
            names[i], got[i], want[i]
        );
        assert!(
            (got[i] - want[i]).abs() < tol[i],
            "{}: ours {} OpenCV {}",
            names[i],
            got[i],
            want[i]
        );
    }
    let cv_cam = Camera::Mei(infraloc::camera::Mei {
        fx: want[0],
        skew: want[1],
        cx: want[2],
        fy: want[3],
        cy: want[4],
        k1: want[5],
        k2: want[6],
        p1: want[7],
        p2: want[8],
        xi: want[9],
        ..m.clone()
    });
    let d = mapping_max(&ours, &cv_cam, 90.0);
    assert!(d < 1.0, "mappings differ by {d} px within 90°");

    // Report: standard deviations for every intrinsic, per-view RMS.
    let params = rep["params"].as_array().unwrap();
    assert_eq!(params.len(), 10);
    for p in params {
        let s = p["std"].as_f64().unwrap();
        assert!(s > 0.0 && s.is_finite(), "{p}");
    }
    // The focal length is known to about 1 %, ξ to a few hundredths (cv::omnidir's own figures
    // for this data are of that order).
    assert!(params[0]["std"].as_f64().unwrap() < 0.02 * m.fx);
    assert!(params[9]["std"].as_f64().unwrap() < 0.05);
    // The camera file states the fit's σ, which localize carries into the pose's covariance:
    // the larger focal length's relative σ and the larger principal-point coordinate's σ.
    let text = std::fs::read_to_string(&yaml).unwrap();
    let key = |k: &str| -> f64 {
        let line = text
            .lines()
            .find(|l| l.starts_with(&format!("{k}:")))
            .unwrap_or_else(|| panic!("{k} missing from\n{text}"));
        line[k.len() + 1..].trim().parse().unwrap()
    };
    let std_of = |name: &str| {
        let p = params.iter().find(|p| p["name"] == name).unwrap();
        (p["std"].as_f64().unwrap(), p["value"].as_f64().unwrap())
    };
    let rel = |n: &str| std_of(n).0 / std_of(n).1;
    let want_f = rel("fx").max(rel("fy"));
    let want_c = std_of("cx").0.max(std_of("cy").0);
    assert!(
        (key("sigma_focal_rel") - want_f).abs() <= 1e-9 * want_f,
        "{text}"
    );
    assert!(
        (key("sigma_principal_point_px") - want_c).abs() <= 1e-9 * want_c,
        "{text}"
    );
    assert!(want_f > 0.0 && want_c > 0.0);
    let img = image::open(&png).unwrap();
    assert_eq!((img.width(), img.height()), (1024, 768));
}

/// Run `calibrate` on `text` written to `name`; returns (exit code, stderr).
fn fails(dir: &Path, name: &str, text: &str) -> (Option<i32>, String) {
    let path: PathBuf = dir.join(name);
    std::fs::write(&path, text).unwrap();
    let out = calibrate(&[
        "--model",
        "mei",
        "--corners",
        path.to_str().unwrap(),
        "--out",
        dir.join("out.yaml").to_str().unwrap(),
    ]);
    assert!(
        !dir.join("out.yaml").exists(),
        "{name}: no output on failure"
    );
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(err.trim_end().lines().count(), 1, "{name}: {err}");
    (out.status.code(), err)
}

#[test]
fn bad_corner_files_fail_with_one_line_naming_file_and_view() {
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(OMNI).unwrap();
    let obs = parse_corners(&text, Path::new(OMNI)).unwrap();
    assert_eq!((obs.width, obs.height, obs.views.len()), (1280, 960, 15));
    // Our YAML writer round-trips through the reader.
    let yaml = to_corners_yaml(&obs);
    assert_eq!(parse_corners(&yaml, Path::new("x.yaml")).unwrap(), obs);

    let mut o = obs.clone();
    o.views.truncate(2);
    let (code, err) = fails(dir.path(), "two.yaml", &to_corners_yaml(&o));
    assert_eq!(code, Some(1));
    assert!(
        err.contains("two.yaml: 2 usable view(s), need at least 3"),
        "{err}"
    );

    let mut o = obs.clone();
    o.views[3].image.pop();
    let (_, err) = fails(dir.path(), "count.yaml", &to_corners_yaml(&o));
    assert!(
        err.contains("count.yaml: view 3: 54 object points but 53 image points"),
        "{err}"
    );

    let mut o = obs.clone();
    o.views[5].image[11] = [1300.0, 400.0];
    let (_, err) = fails(dir.path(), "outside.yaml", &to_corners_yaml(&o));
    assert!(
        err.contains(
            "outside.yaml: view 5: corner 11 at (1300.0, 400.0) lies outside the 1280×960 image"
        ),
        "{err}"
    );

    let mut o = obs.clone();
    o.views.clear();
    let (_, err) = fails(dir.path(), "none.yaml", &to_corners_yaml(&o));
    assert!(
        err.contains("none.yaml: no board found in any view"),
        "{err}"
    );

    // One view fewer in imagePoints than in objectPoints.
    let cut = text.rfind("<_ type_id=\"opencv-matrix\">").unwrap();
    let end = text.rfind("</_>").unwrap() + "</_>".len();
    let (_, err) = fails(
        dir.path(),
        "short.xml",
        &format!("{}{}", &text[..cut], &text[end..]),
    );
    assert!(
        err.contains("short.xml: objectPoints has 15 views but imagePoints has 14"),
        "{err}"
    );

    let (_, err) = fails(
        dir.path(),
        "nosize.xml",
        &text.replace("<imageSize>\n  1280 960</imageSize>\n", ""),
    );
    assert!(err.contains("nosize.xml: missing key imageSize"), "{err}");
}

/// OpenCV's corners of the tutorial's real sample image: findChessboardCorners + cornerSubPix.
const CV_SAMPLE_CORNERS: &str = r#"
import sys, cv2
im = cv2.imread(sys.argv[1], cv2.IMREAD_GRAYSCALE)
ok, c = cv2.findChessboardCorners(im, (9, 6), cv2.CALIB_CB_ADAPTIVE_THRESH + cv2.CALIB_CB_NORMALIZE_IMAGE)
assert ok, "OpenCV finds no board"
c = cv2.cornerSubPix(im, c, (5, 5), (-1, -1), (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 30, 1e-3))
print(*[repr(float(v)) for v in c.ravel()])
"#;

/// Our detector on a real omnidirectional image (opencv_contrib's `sample.jpg`, a 9×6 board near
/// the mirror's edge): every corner found, within 0.15 px of OpenCV's sub-pixel corners.
#[test]
fn real_sample_image_corners_match_opencv() {
    let path = Path::new(OMNI).with_file_name("sample.jpg");
    let img = image::open(&path).unwrap().into_luma8();
    let (w, h) = img.dimensions();
    let found = infraloc::calib::detect::detect(img.as_raw(), w, h, 9, 6, 0.04).unwrap();
    assert!(found.full);
    assert_eq!(found.image.len(), 54);
    let cv = nums(&python(CV_SAMPLE_CORNERS, &[&path]));
    assert_eq!(cv.len(), 108);
    let (mut sum, mut max) = (0.0f64, 0.0f64);
    for p in &found.image {
        let d = cv
            .chunks(2)
            .map(|c| (c[0] - p[0]).hypot(c[1] - p[1]))
            .fold(f64::MAX, f64::min);
        sum += d;
        max = max.max(d);
    }
    let mean = sum / 54.0;
    eprintln!("sample.jpg: ours vs OpenCV mean {mean:.3} px, max {max:.3} px");
    assert!(mean < 0.1 && max < 0.15, "mean {mean} max {max}");
}
