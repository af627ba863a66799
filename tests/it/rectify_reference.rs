//! `infraloc rectify` against OpenCV: maps from `cv2.omnidir.initUndistortRectifyMap(…,
//! RECTIFY_PERSPECTIVE)` / `cv2.fisheye.initUndistortRectifyMap` and images from `cv2.remap`, made by
//! `tests/reference/make_rectify_refs.py` from the shared OpenCV sample image.

use std::path::{Path, PathBuf};
use std::process::Command;

const SAMPLE: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../shared/data/omnidir/sample.jpg"
);
const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/rectify");

/// Map agreement required where OpenCV maps into the source image (px).
const MAP_TOL: f32 = 1e-3;
/// Image agreement required (grey levels). The remap itself is bit-exact (see the unit tests and
/// docs/rectify.md); the ±1 comes from JPEG decoding (image/zune-jpeg vs libjpeg-turbo in OpenCV).
const IMAGE_TOL: i32 = 1;

#[derive(serde::Deserialize)]
struct Case {
    size: [usize; 2],
    k: [f64; 4],
    rotation: [f64; 9],
}

fn join(v: &[f64]) -> String {
    // `{:?}` prints the shortest string that parses back to the same f64.
    v.iter()
        .map(|x| format!("{x:?}"))
        .collect::<Vec<_>>()
        .join(",")
}

fn read_planes(path: &Path, n: usize) -> (Vec<f32>, Vec<f32>) {
    let bytes = std::fs::read(path).unwrap();
    assert_eq!(bytes.len(), 8 * n, "{}", path.display());
    let all: Vec<f32> = bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    (all[..n].to_vec(), all[n..].to_vec())
}

/// Run the binary on one case; returns (max map difference, pixels compared, max image
/// difference, pixels differing at all).
fn run_case(name: &str, camera: &str) -> (f32, usize, i32, usize) {
    let dir = PathBuf::from(DATA).join(name);
    let case: Case =
        serde_json::from_str(&std::fs::read_to_string(dir.join("case.json")).unwrap()).unwrap();
    let [w, h] = case.size;
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out.png");
    let maps = tmp.path().join("map.f32");
    let st = Command::new(env!("CARGO_BIN_EXE_infraloc"))
        .args(["rectify", "--camera"])
        .arg(dir.join(camera))
        .arg("--image")
        .arg(SAMPLE)
        .arg("--out")
        .arg(&out)
        .args(["--size", &format!("{w},{h}")])
        .args(["--k", &join(&case.k)])
        .args(["--rotation", &join(&case.rotation)])
        .arg("--map-out")
        .arg(&maps)
        .output()
        .unwrap();
    assert!(
        st.status.success(),
        "{name}: {}",
        String::from_utf8_lossy(&st.stderr)
    );

    // Maps: compare where OpenCV's coordinate lies inside the 640×480 source.
    let (rx, ry) = read_planes(&dir.join("map.f32"), w * h);
    let (mx, my) = read_planes(&maps, w * h);
    let (sw, sh) = (640.0, 480.0);
    let mut max_map = 0f32;
    let mut compared = 0;
    for i in 0..w * h {
        if rx[i] >= 0.0 && ry[i] >= 0.0 && rx[i] <= sw - 1.0 && ry[i] <= sh - 1.0 {
            max_map = max_map
                .max((mx[i] - rx[i]).abs())
                .max((my[i] - ry[i]).abs());
            compared += 1;
        }
    }

    // Images: every pixel, borders included.
    let ours = image::open(&out).unwrap().to_luma8();
    let cv = image::open(dir.join("out.png")).unwrap().to_luma8();
    assert_eq!(ours.dimensions(), cv.dimensions());
    let diffs: Vec<i32> = ours
        .as_raw()
        .iter()
        .zip(cv.as_raw())
        .map(|(&a, &b)| (a as i32 - b as i32).abs())
        .collect();
    let max_img = diffs.iter().copied().max().unwrap();
    let n_diff = diffs.iter().filter(|&&d| d > 0).count();
    eprintln!("{name}: max map diff {max_map:e} px over {compared} px, max image diff {max_img}, {n_diff} px differ");
    (max_map, compared, max_img, n_diff)
}

fn check(name: &str, camera: &str, min_compared: usize) {
    let (max_map, compared, max_img, _) = run_case(name, camera);
    assert!(
        compared >= min_compared,
        "{name}: only {compared} pixels compared"
    );
    assert!(max_map <= MAP_TOL, "{name}: map differs by {max_map} px");
    assert!(max_img <= IMAGE_TOL, "{name}: image differs by {max_img}");
}

#[test]
fn mei_matches_opencv_omnidir() {
    check("mei_a", "camera.toml", 320 * 240);
}

#[test]
fn mei_with_skew_and_borders_matches_opencv_omnidir() {
    // Wide view: about 6 % of the output falls outside the source (exercises the border path).
    // Camera read from the FileStorage YAML that cv2 itself wrote.
    check("mei_skew", "camera.yaml", 200 * 150 * 9 / 10);
}

#[test]
fn equidistant_matches_opencv_fisheye_in_front_of_the_camera() {
    check("equidistant", "camera.toml", 160 * 120);
}

#[test]
fn bad_arguments_are_one_line_errors() {
    let dir = PathBuf::from(DATA).join("mei_a");
    let tmp = tempfile::tempdir().unwrap();
    let run = |extra: &[&str]| {
        let o = Command::new(env!("CARGO_BIN_EXE_infraloc"))
            .args(["rectify", "--camera"])
            .arg(dir.join("camera.toml"))
            .arg("--image")
            .arg(SAMPLE)
            .arg("--out")
            .arg(tmp.path().join("o.png"))
            .args(extra)
            .output()
            .unwrap();
        assert!(!o.status.success());
        let e = String::from_utf8_lossy(&o.stderr).to_string();
        assert_eq!(e.trim_end().lines().count(), 1, "{e}");
        e
    };
    assert!(run(&["--size", "10", "--k", "1,1,1,1"]).contains("--size"));
    assert!(run(&["--size", "10,10", "--k", "1,1,x,1"]).contains("--k"));
    assert!(run(&[
        "--size",
        "10,10",
        "--k",
        "1,1,1,1",
        "--rotation",
        "0,0,0,0,0,0,0,0,0"
    ])
    .contains("--rotation is not a rotation matrix"));
    // Scaled, sheared and mirrored matrices would zoom, skew or flip the output: refused.
    for r in [
        "2,0,0,0,2,0,0,0,2",
        "1,0.2,0,0,1,0,0,0,1",
        "-1,0,0,0,1,0,0,0,1",
    ] {
        let e = run(&["--size", "10,10", "--k", "1,1,1,1", "--rotation", r]);
        assert!(
            e.contains("--rotation is not a rotation matrix"),
            "{r}: {e}"
        );
    }
}
