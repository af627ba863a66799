//! `infraloc calibrate --images` on boards rendered by `infraloc simulate --checkerboard` (issue 15's
//! acceptance): for Mei lenses with ξ 0.8, 1.5 and 2.2 and an equidistant lens, the calibrated
//! model maps rays to pixels like the true camera over the field the boards covered — mean
//! ≤ 0.15 px, max ≤ 0.4 px — and the principal point is within 0.5 px. Mappings are compared, not
//! parameters (Mei's focal and ξ trade against each other). Plus determinism of the renderer and
//! the bad-input lines of the image path.

use infraloc::camera::{load_camera, Camera, CameraModel};
use nalgebra::Point2;
use std::path::Path;
use std::process::{Command, Output};

/// Image size of the test cameras: small, so the test stays quick in CI.
const W: u32 = 800;
const H: u32 = 600;
/// Views rendered per camera.
const VIEWS: &str = "24";

fn infraloc(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_infraloc"))
        .args(args)
        .output()
        .expect("run infraloc")
}

fn ok(out: Output) -> String {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// `infraloc simulate --checkerboard N --camera CAM --seed S --out DIR`.
fn simulate_boards(cam: &Path, n: &str, seed: &str, out: &Path) {
    ok(infraloc(&[
        "simulate",
        "--checkerboard",
        n,
        "--camera",
        cam.to_str().unwrap(),
        "--seed",
        seed,
        "--out",
        out.to_str().unwrap(),
    ]));
}

/// OpenCV FileStorage YAML of a Mei camera with radius `r90` px at 90° from the axis.
fn mei_yaml(xi: f64) -> String {
    let gamma = 330.0 * xi;
    format!(
        "%YAML:1.0\n---\nmodel: mei\nimage_width: {W}\nimage_height: {H}\n\
         camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   \
         data: [ {gamma}, 0.0, 401.3, 0.0, {}, 298.2, 0.0, 0.0, 1.0 ]\n\
         distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 4\n   dt: d\n   \
         data: [ -0.03, 0.006, 2.0e-4, -1.0e-4 ]\nxi: {xi}\n",
        gamma * 1.002
    )
}

fn equidistant_yaml() -> String {
    format!(
        "%YAML:1.0\n---\nmodel: equidistant\nimage_width: {W}\nimage_height: {H}\n\
         camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   \
         data: [ 212.0, 0.0, 398.6, 0.0, 212.4, 301.1, 0.0, 0.0, 1.0 ]\n\
         distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 4\n   dt: d\n   \
         data: [ -0.012, 0.0015, -2.0e-4, 2.0e-5 ]\n"
    )
}

fn principal_point(c: &Camera) -> (f64, f64) {
    match c {
        Camera::Mei(m) => (m.cx, m.cy),
        Camera::Equidistant(e) => (e.cx, e.cy),
    }
}

/// The quads of adjacent detected corners of a `--save-corners` file: the field the boards
/// covered, as the pixels of every grid cell whose four corners were found.
fn covered_quads(path: &Path) -> Vec<[[f64; 2]; 4]> {
    let text = std::fs::read_to_string(path).unwrap();
    let obs = infraloc::calib::corners::parse_corners(&text, path).unwrap();
    let mut quads = Vec::new();
    for v in &obs.views {
        let s = v.object[1][0] - v.object[0][0];
        let key = |o: &[f64; 3]| ((o[0] / s).round() as i64, (o[1] / s).round() as i64);
        let at: std::collections::HashMap<(i64, i64), [f64; 2]> = v
            .object
            .iter()
            .map(key)
            .zip(v.image.iter().copied())
            .collect();
        for &(i, j) in at.keys() {
            if let (Some(a), Some(b), Some(c), Some(d)) = (
                at.get(&(i, j)),
                at.get(&(i + 1, j)),
                at.get(&(i + 1, j + 1)),
                at.get(&(i, j + 1)),
            ) {
                quads.push([*a, *b, *c, *d]);
            }
        }
    }
    quads
}

/// Whether `p` lies inside the quad (corners in order around it, either sense).
fn in_quad(q: &[[f64; 2]; 4], p: [f64; 2]) -> bool {
    let side =
        |a: [f64; 2], b: [f64; 2]| (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]);
    let s: Vec<f64> = (0..4).map(|k| side(q[k], q[(k + 1) % 4])).collect();
    s.iter().all(|v| *v >= 0.0) || s.iter().all(|v| *v <= 0.0)
}

/// Render, detect, calibrate; returns (mean, max) mapping error over the covered pixels and the
/// principal point error.
fn round_trip(name: &str, model: &str, yaml: &str, seed: &str) -> (f64, f64, f64) {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cam_path = d.join("true.yaml");
    std::fs::write(&cam_path, yaml).unwrap();
    let boards = d.join("boards");
    simulate_boards(&cam_path, VIEWS, seed, &boards);
    let (fit, corners, report) = (d.join("fit.yaml"), d.join("det.yaml"), d.join("rep.json"));
    let stdout = ok(infraloc(&[
        "calibrate",
        "--model",
        model,
        "--images",
        boards.to_str().unwrap(),
        "--pattern",
        "9x6",
        "--square",
        "0.04",
        "--out",
        fit.to_str().unwrap(),
        "--save-corners",
        corners.to_str().unwrap(),
        "--report",
        report.to_str().unwrap(),
    ]));
    let truth = load_camera(&cam_path).unwrap();
    let ours = load_camera(&fit).unwrap();
    let quads = covered_quads(&corners);
    // The field the boards covered: pixels on a 2 px lattice inside a cell of detected corners.
    let (mut sum, mut max, mut n) = (0.0f64, 0.0f64, 0usize);
    for v in (0..H).step_by(2) {
        for u in (0..W).step_by(2) {
            let (x, y) = (u as f64, v as f64);
            if !quads.iter().any(|q| in_quad(q, [x, y])) {
                continue;
            }
            let px = Point2::new(x, y);
            let ray = truth.unproject(&px).expect("board pixels are in the lens");
            let back = ours.project(&ray).expect("the fit maps every covered ray");
            let e = (back - px).norm();
            sum += e;
            max = max.max(e);
            n += 1;
        }
    }
    assert!(n > 1000, "{name}: only {n} covered pixels");
    let mean = sum / n as f64;
    let (a, b) = (principal_point(&truth), principal_point(&ours));
    let pp = (a.0 - b.0).hypot(a.1 - b.1);
    eprintln!(
        "{name}: {} cells, {n} covered pixels, mapping mean {mean:.4} px max {max:.4} px, \
         principal point off by {pp:.4} px; {}",
        quads.len(),
        stdout.trim()
    );
    (mean, max, pp)
}

#[test]
fn calibrated_mappings_match_the_true_cameras() {
    let cases: Vec<(String, &str, String, &str)> = vec![
        ("mei xi 0.8".into(), "mei", mei_yaml(0.8), "1"),
        ("mei xi 1.5".into(), "mei", mei_yaml(1.5), "2"),
        ("mei xi 2.2".into(), "mei", mei_yaml(2.2), "3"),
        ("equidistant".into(), "equidistant", equidistant_yaml(), "4"),
    ];
    let mut failures = Vec::new();
    for (name, model, yaml, seed) in &cases {
        let (mean, max, pp) = round_trip(name, model, yaml, seed);
        if !(mean <= 0.15 && max <= 0.4 && pp <= 0.5) {
            failures.push(format!("{name}: mean {mean:.3} max {max:.3} pp {pp:.3}"));
        }
    }
    assert!(failures.is_empty(), "{failures:?}");
}

#[test]
fn simulated_boards_are_deterministic() {
    let dir = tempfile::tempdir().unwrap();
    let cam = dir.path().join("true.yaml");
    std::fs::write(&cam, mei_yaml(1.1)).unwrap();
    let run = |sub: &str, seed: &str| {
        let out = dir.path().join(sub);
        simulate_boards(&cam, "2", seed, &out);
        [
            "000.png",
            "001.png",
            "checkerboard.json",
            "corners.yaml",
            "camera.yaml",
        ]
        .iter()
        .map(|f| std::fs::read(out.join(f)).unwrap())
        .collect::<Vec<_>>()
    };
    let (a, b, c) = (run("a", "7"), run("b", "7"), run("c", "8"));
    assert_eq!(a, b, "same seed, same bytes");
    assert_ne!(a[0], c[0], "another seed, another view");
    // The true corners file is the --corners layout and agrees with checkerboard.json.
    let truth: serde_json::Value = serde_json::from_slice(&a[2]).unwrap();
    assert_eq!(truth["pattern"], serde_json::json!([9, 6]));
    assert_eq!(truth["views"][0]["corners"].as_array().unwrap().len(), 54);
    // The truth names real pixels: some view has its corners in the image, not only nulls.
    let seen: usize = truth["views"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| {
            v["corners"]
                .as_array()
                .unwrap()
                .iter()
                .filter(|c| !c.is_null())
                .count()
        })
        .sum();
    assert!(seen > 0, "no true corner in any view");
    let obs = infraloc::calib::corners::parse_corners(
        std::str::from_utf8(&a[3]).unwrap(),
        Path::new("corners.yaml"),
    )
    .unwrap();
    assert_eq!((obs.width, obs.height), (W, H));
}

/// Run `calibrate --images DIR`; asserts one line on stderr, a non-zero exit and no output file.
fn images_fail(dir: &Path) -> String {
    let out_path = dir.join("out.yaml");
    let out = infraloc(&[
        "calibrate",
        "--model",
        "mei",
        "--images",
        dir.to_str().unwrap(),
        "--pattern",
        "9x6",
        "--square",
        "0.04",
        "--out",
        out_path.to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(1));
    assert!(!out_path.exists(), "no output on failure");
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    err
}

#[test]
fn bad_image_sets_fail_with_one_line_naming_the_directory_and_images() {
    let tmp = tempfile::tempdir().unwrap();
    // No board in any image: plain grey frames.
    let blank = tmp.path().join("blank");
    std::fs::create_dir(&blank).unwrap();
    for i in 0..3 {
        image::GrayImage::from_pixel(W, H, image::Luma([90]))
            .save(blank.join(format!("{i}.png")))
            .unwrap();
    }
    let err = images_fail(&blank);
    assert!(
        err.contains(&format!(
            "{}: no 9x6 board found in any of 3 image(s) (0.png: ",
            blank.display()
        )),
        "{err}"
    );

    // Too few views: two boards.
    let cam = tmp.path().join("true.yaml");
    std::fs::write(&cam, mei_yaml(1.5)).unwrap();
    let two = tmp.path().join("two");
    simulate_boards(&cam, "2", "1", &two);
    for f in ["camera.yaml", "corners.yaml", "checkerboard.json"] {
        std::fs::remove_file(two.join(f)).unwrap();
    }
    let err = images_fail(&two);
    assert!(
        err.contains(&format!(
            "{}: a board in 2 image(s), need at least 3",
            two.display()
        )),
        "{err}"
    );

    // Images of different sizes: named.
    let mixed = tmp.path().join("mixed");
    std::fs::create_dir(&mixed).unwrap();
    for (i, f) in ["000.png", "001.png", "000.png"].iter().enumerate() {
        std::fs::copy(two.join(f), mixed.join(format!("{i}.png"))).unwrap();
    }
    let small = image::imageops::resize(
        &image::open(two.join("000.png")).unwrap().into_luma8(),
        W / 2,
        H / 2,
        image::imageops::FilterType::Triangle,
    );
    small.save(mixed.join("3.png")).unwrap();
    let err = images_fail(&mixed);
    assert!(
        err.contains("3.png: image is 400×300 but 0.png is 800×600"),
        "{err}"
    );

    // An empty directory.
    let empty = tmp.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    let err = images_fail(&empty);
    assert!(err.contains("empty: no images"), "{err}");
}

#[test]
fn fronto_parallel_boards_are_refused_as_degenerate() {
    let dir = tempfile::tempdir().unwrap();
    let cam_path = dir.path().join("true.yaml");
    std::fs::write(&cam_path, mei_yaml(1.5)).unwrap();
    let cam = load_camera(&cam_path).unwrap();
    let board: Vec<[f64; 3]> = (0..6)
        .flat_map(|j| (0..9).map(move |i| [i as f64 * 0.04, j as f64 * 0.04, 0.0]))
        .collect();
    // Four boards square to the axis, moved across the image: no tilt, so focal and distance
    // trade against each other.
    let views = [(-0.3, -0.2), (0.1, -0.25), (-0.25, 0.05), (0.05, 0.0)]
        .iter()
        .enumerate()
        .map(|(k, (x, y))| infraloc::calib::View {
            name: format!("view {k}"),
            object: board.clone(),
            image: board
                .iter()
                .map(|p| {
                    let q = cam
                        .project(&nalgebra::Vector3::new(p[0] + x, p[1] + y, 0.6))
                        .unwrap();
                    [q.x, q.y]
                })
                .collect(),
        })
        .collect();
    let obs = infraloc::calib::Observations {
        width: W,
        height: H,
        views,
    };
    let file = dir.path().join("flat.yaml");
    std::fs::write(&file, infraloc::calib::corners::to_corners_yaml(&obs)).unwrap();
    let out_path = dir.path().join("out.yaml");
    let out = infraloc(&[
        "calibrate",
        "--model",
        "mei",
        "--corners",
        file.to_str().unwrap(),
        "--out",
        out_path.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(!out_path.exists());
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(
        err.contains("flat.yaml: degenerate views: all 4 boards are fronto-parallel"),
        "{err}"
    );
}
