//! `infraloc refine` through the binary: a synthetic scene written to files, then good and bad
//! invocations.

use infraloc::camera::import::to_opencv_yaml;
use infraloc::camera::{Camera, Mei};
use infraloc::localize::synth::{ground_points, render, Texture};
use infraloc::map::Crs;
use infraloc::pose::{rotation_angle_between, CamFromMap};
use infraloc::posefile::{read_pose, PoseFile};
use nalgebra::{Point3, Vector3};
use std::path::Path;
use std::process::Command;

fn write_scene(dir: &Path) -> CamFromMap {
    let cam = Camera::Mei(Mei {
        width: 320,
        height: 320,
        fx: 190.0,
        fy: 190.0,
        cx: 160.2,
        cy: 158.9,
        skew: 0.0,
        xi: 1.2,
        k1: -0.04,
        k2: 0.008,
        p1: 0.0,
        p2: 0.0,
        fov_deg: Some(185.0),
    });
    let tex = Texture::new(77);
    let truth =
        CamFromMap::from_center_ypr(&Point3::new(500_010.0, 4_400_020.0, 206.0), 1.0, 0.0, 0.0);
    let (gray, _) = render(&tex, &cam, &truth, 200.0, 4.0, 1);
    image::GrayImage::from_raw(320, 320, gray)
        .unwrap()
        .save(dir.join("frame.png"))
        .unwrap();
    std::fs::write(dir.join("camera.yaml"), to_opencv_yaml(&cam)).unwrap();
    let pts = ground_points(&tex, (500_010.0, 4_400_020.0), 10.0, 0.15, 200.0, 4.0, 2);
    let mut csv = String::from("x,y,z,reflectivity\n");
    for p in &pts {
        csv += &format!("{},{},{},{}\n", p.x, p.y, p.z, p.reflectivity);
    }
    std::fs::write(dir.join("points.csv"), csv).unwrap();
    let init = truth.perturbed(&Vector3::new(0.07, -0.05, 0.03), 0.3f64.to_radians());
    let pf = PoseFile::new(&init, Crs::Epsg(32617), "t", "2026-11-21T12:00:00Z".into());
    std::fs::write(dir.join("init.json"), pf.to_json()).unwrap();
    truth
}

/// Run `infraloc refine` on the scene in `dir` (pose to out.json, report to report.json) with the
/// default test box unless `extra` has `--search`.
fn refine_output(dir: &Path, extra: &[&str]) -> std::process::Output {
    let mut args = vec![
        "refine".to_string(),
        "--camera".into(),
        dir.join("camera.yaml").display().to_string(),
        "--image".into(),
        dir.join("frame.png").display().to_string(),
        "--points".into(),
        dir.join("points.csv").display().to_string(),
        "--init".into(),
        dir.join("init.json").display().to_string(),
        "--out".into(),
        dir.join("out.json").display().to_string(),
        "--report".into(),
        dir.join("report.json").display().to_string(),
    ];
    if !extra.contains(&"--search") {
        args.push("--search".into());
        args.push("x=0.16:0.02,y=0.16:0.02,z=0.1:0.02,yaw=0.6:0.05".into());
    }
    for e in extra {
        args.push(e.to_string());
    }
    Command::new(env!("CARGO_BIN_EXE_infraloc"))
        .args(&args)
        .output()
        .unwrap()
}

/// Whether a refine run served its result: exit 0 (precise) or 5 (coarse).
fn served(o: &std::process::Output) -> bool {
    matches!(o.status.code(), Some(0 | 5))
}

fn refine(dir: &Path, extra: &[&str]) -> (bool, String) {
    let o = refine_output(dir, extra);
    (served(&o), String::from_utf8_lossy(&o.stderr).into_owned())
}

fn read_report(dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap()).unwrap()
}

#[test]
fn refine_cli_estimator_flags() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    write_scene(dir);
    // Grid only: the two runs differ in the objective alone, not in a polish's path.
    let (ok, err) = refine(dir, &["--grid-only"]);
    assert!(ok, "{err}");
    let mi = read_report(dir);
    assert_eq!(
        mi["estimator"],
        serde_json::json!({"bins-reflectivity": 32, "bins-gray": 32, "binning": "equalized",
            "objective": "mi", "parzen": true, "pooling": "per-pair"}),
        "{mi}"
    );
    assert_eq!(mi["score"]["objective"], "mi");
    assert_eq!(mi["score"]["value"], mi["quality"]["mi"]);

    let (ok, err) = refine(
        dir,
        &[
            "--grid-only",
            "--objective",
            "nmi",
            "--bins",
            "16",
            "--no-parzen",
        ],
    );
    assert!(ok, "{err}");
    let nmi = read_report(dir);
    assert_eq!(nmi["estimator"]["objective"], "nmi", "{nmi}");
    assert_eq!(nmi["estimator"]["bins-gray"], 16);
    assert_eq!(nmi["estimator"]["bins-reflectivity"], 16);
    assert_eq!(nmi["estimator"]["parzen"], false);
    assert_eq!(nmi["score"]["objective"], "nmi");
    assert_eq!(nmi["score"]["value"], nmi["quality"]["nmi"]);
    // NMI lies in [1, 2] and the profile's background is in the objective's unit: both show
    // that NMI, not MI (well below 1 nat here), is what was maximised.
    let v = nmi["score"]["value"].as_f64().unwrap();
    assert!(v > 1.0 && v <= 2.0, "{v}");
    assert!(mi["score"]["value"].as_f64().unwrap() < 1.0, "{mi}");
    assert!(
        nmi["quality"]["background"].as_f64().unwrap() >= 1.0,
        "{nmi}"
    );
    assert!(mi["quality"]["background"].as_f64().unwrap() < 1.0, "{mi}");

    // Bad values: one line naming the flag, the refine CLI's exit code 1, no pose written.
    for (extra, flag) in [
        (&["--objective", "entropy"][..], "--objective"),
        (&["--objective", "NMI"], "--objective"),
        (&["--bins", "1"], "--bins"),
        (&["--bins", "300"], "--bins"),
        (&["--bins", "many"], "--bins"),
        (&["--binning", "log"], "--binning"),
    ] {
        std::fs::remove_file(dir.join("out.json")).ok();
        let o = refine_output(dir, extra);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{extra:?}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{extra:?}: {err}");
        assert!(err.contains(flag), "{extra:?}: {err}");
        assert!(!dir.join("out.json").exists(), "{extra:?}: pose written");
    }

    // The flags are in --help.
    let o = Command::new(env!("CARGO_BIN_EXE_infraloc"))
        .args(["refine", "--help"])
        .output()
        .unwrap();
    let help = String::from_utf8_lossy(&o.stdout);
    for flag in ["--bins", "--objective", "--binning", "--no-parzen"] {
        assert!(help.contains(flag), "{flag} missing from refine --help");
    }
}

#[test]
fn refine_cli_end_to_end_and_bad_input() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let truth = write_scene(dir);
    let (ok, err) = refine(dir, &[]);
    assert!(ok, "{err}");
    let out = read_pose(&dir.join("out.json")).unwrap().pose;
    let e = out.center() - truth.center();
    assert!(
        e.x.abs() <= 0.03 && e.y.abs() <= 0.03 && e.z.abs() <= 0.04,
        "{e:?}"
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["quality"]["accepted"], true);
    assert!(report["evaluation_ratio"].as_f64().unwrap() > 1.0);
    // By default the smooth estimator's 4-DoF ascent follows the search: roll and pitch
    // untouched, and the competing optima were looked for.
    assert_eq!(report["finish"], "4-dof-gradient");
    for asc in report["smooth"]["ascents"].as_array().unwrap() {
        assert_eq!(
            (asc["theta"][3].as_f64(), asc["theta"][4].as_f64()),
            (Some(0.0), Some(0.0)),
            "{asc}"
        );
    }
    assert!(report["quality"]["optima"]["starts"].as_u64().unwrap() > 0);
    let tilt = |p: &infraloc::pose::CamFromMap| {
        let (_, pitch, roll) = p.yaw_pitch_roll();
        (pitch, roll)
    };
    let init = read_pose(&dir.join("init.json")).unwrap().pose;
    let ((p0, r0), (p1, r1)) = (tilt(&init), tilt(&out));
    assert!((p0 - p1).abs() < 1e-12 && (r0 - r1).abs() < 1e-12);

    // --grid-only answers the search's cell (no rounds); --polish and --grid-only conflict.
    // --overlay: the before (init) and after panels side by side.
    let overlay = dir.join("overlay.png");
    let (ok, err) = refine(
        dir,
        &["--grid-only", "--overlay", overlay.to_str().unwrap()],
    );
    assert!(ok, "{err}");
    let png = image::open(&overlay).unwrap().to_rgb8();
    assert_eq!((png.width(), png.height()), (640, 320));
    let cyan = |x0: u32| {
        (x0..x0 + 320)
            .flat_map(|x| (0..320).map(move |y| (x, y)))
            .filter(|&(x, y)| png.get_pixel(x, y).0 == [0, 255, 255])
            .count()
    };
    // Both panels carry points (the brightest 4 % of ≈ 14 k).
    assert!(
        cyan(0) > 100 && cyan(320) > 100,
        "{} {}",
        cyan(0),
        cyan(320)
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["finish"], "none");
    assert!(report.get("rounds").is_none());
    let (ok, err) = refine(dir, &["--grid-only", "--polish"]);
    assert!(!ok && err.contains("cannot be used with"), "{err}");

    // Bad inputs: one line on stderr, non-zero exit, no pose written.
    let bad = |name: &str, setup: &dyn Fn(&Path), extra: &[&str], want: &str| {
        std::fs::remove_file(dir.join("out.json")).ok();
        let d = tempfile::tempdir().unwrap();
        for f in ["camera.yaml", "frame.png", "points.csv", "init.json"] {
            std::fs::copy(dir.join(f), d.path().join(f)).unwrap();
        }
        setup(d.path());
        let (ok, err) = refine(d.path(), extra);
        assert!(!ok, "{name}: should fail");
        assert_eq!(err.trim().lines().count(), 1, "{name}: {err}");
        assert!(err.contains(want), "{name}: {err}");
        assert!(!d.path().join("out.json").exists(), "{name}: pose written");
    };
    bad(
        "empty points",
        &|d| std::fs::write(d.join("points.csv"), "x,y,z,reflectivity\n").unwrap(),
        &[],
        "no ground points",
    );
    bad(
        "NaN height",
        &|d| {
            std::fs::write(
                d.join("points.csv"),
                "x,y,z,reflectivity\n500010,4400020,NaN,3\n",
            )
            .unwrap()
        },
        &[],
        "non-finite",
    );
    bad(
        "image size",
        &|d| {
            image::GrayImage::new(100, 80)
                .save(d.join("frame.png"))
                .unwrap()
        },
        &[],
        "100×80",
    );
    bad(
        "invisible points",
        &|d| {
            std::fs::write(
                d.join("points.csv"),
                "x,y,z,reflectivity\n500010,4400020,900,3\n",
            )
            .unwrap()
        },
        &[],
        "none is visible",
    );
    bad("zero range", &|_| {}, &["--search", "x=0:0.02"], "--search");
    bad(
        "absurd range",
        &|_| {},
        &["--search", "yaw=400:1"],
        "--search",
    );
}

#[test]
fn refine_cli_polish_frees_the_tilt() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let truth = write_scene(dir);
    // An initial pose whose roll/pitch are off, as PnP's are.
    let (y, p, r) = truth.yaw_pitch_roll();
    let init = CamFromMap::from_center_ypr(
        &(truth.center() + Vector3::new(0.05, -0.04, 0.02)),
        y + 0.2f64.to_radians(),
        p + 1.0f64.to_radians(),
        r - 0.8f64.to_radians(),
    );
    let pf = PoseFile::new(&init, Crs::Epsg(32617), "t", "2026-11-21T12:00:00Z".into());
    std::fs::write(dir.join("init.json"), pf.to_json()).unwrap();
    let rot_err = |dir: &Path| {
        let out = read_pose(&dir.join("out.json")).unwrap().pose;
        rotation_angle_between(&out.rotation, &truth.rotation).to_degrees()
    };
    // A box wide enough for the 4-DoF search's tilt-for-position trade (≈ h·tilt ≈ 10 cm). A
    // 320-px frame pins yaw to about 0.2° (1σ), above the node's 0.15° limit.
    let search = [
        "--search",
        "x=0.4:0.02,y=0.4:0.02,z=0.2:0.02,yaw=1.5:0.05",
        "--max-sigma",
        "yaw=0.4",
    ];
    let (ok, err) = refine(dir, &search);
    assert!(ok, "{err}");
    let plain = rot_err(dir);
    eprintln!("rotation error: 4-DoF {plain:.3}°");
    assert!(plain > 1.0, "the 4-DoF refinement cannot tilt: {plain}°");
    // The default stage with --polish ascends over all six axes from the grid's cell: the tilt
    // moves, and the result (accepted or refused) is one line either way.
    let out = refine_output(dir, &[&search[..], &["--polish"]].concat());
    let report = read_report(dir);
    assert_eq!(report["finish"], "6-dof-gradient", "{report}");
    let theta = &report["smooth"]["ascents"][0]["theta"];
    let tilt_moved = theta[3].as_f64().unwrap().hypot(theta[4].as_f64().unwrap());
    assert!(tilt_moved > 0.0, "{report}");
    if served(&out) {
        let polished = rot_err(dir);
        eprintln!("rotation error: 6-DoF {polished:.3}°");
        assert!(polished < plain, "6-DoF {polished}° vs 4-DoF {plain}°");
    } else {
        assert_eq!(
            String::from_utf8_lossy(&out.stderr).trim().lines().count(),
            1
        );
    }
}

/// `pitch=`/`roll=` in `--search` make the grid 6-DoF (off by default): from a start whose tilt
/// is 1° / 0.8° off, the grid's own cell has the tilt right, and the summary line says so.
#[test]
fn refine_cli_grid_searches_pitch_and_roll_when_asked() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let truth = write_scene(dir);
    let (y, p, r) = truth.yaw_pitch_roll();
    let init = CamFromMap::from_center_ypr(
        &(truth.center() + Vector3::new(0.04, -0.04, 0.02)),
        y + 0.1f64.to_radians(),
        p + 1.0f64.to_radians(),
        r - 0.75f64.to_radians(),
    );
    let pf = PoseFile::new(&init, Crs::Epsg(32617), "t", "2026-11-21T12:00:00Z".into());
    std::fs::write(dir.join("init.json"), pf.to_json()).unwrap();
    let out = refine_output(
        dir,
        &[
            "--grid-only",
            "--search",
            "x=0.1:0.02,y=0.1:0.02,z=0.06:0.02,yaw=0.3:0.05,pitch=1.5:0.25,roll=1.5:0.25",
        ],
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let pose = read_pose(&dir.join("out.json")).unwrap().pose;
    let rot = rotation_angle_between(&pose.rotation, &truth.rotation).to_degrees();
    eprintln!("{stdout}rotation error {rot:.3}° (start 1.26°)");
    assert!(rot < 0.3, "rotation error {rot}°");
    assert!(
        stdout.contains("pitch -1.") && stdout.contains("roll +0.7"),
        "{stdout}"
    );
    let report = read_report(dir);
    assert_eq!(
        report["offsets"].as_array().map(|a| a.len()),
        Some(6),
        "{report}"
    );
}

/// A refine run with arbitrary arguments after `refine`.
/// `--starts 3`: three refinements, the first from `--init` and two spread around it, each
/// reported with its verdict; the accepted answers are compared within their combined 3σ; the
/// default stage reports the competing optima it looked for; a bad `--start-spread` is one line.
#[test]
fn refine_cli_self_check_from_several_starts() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    write_scene(dir);
    let out = refine_output(dir, &["--starts", "3"]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let report = read_report(dir);
    let check = &report["self_check"];
    let starts = check["starts"].as_array().expect("the self-check's starts");
    assert_eq!(starts.len(), 3, "{report}");
    assert_eq!(starts[0]["start"][0].as_f64(), Some(0.0));
    assert!(
        (starts[1]["start"][0].as_f64().unwrap() - 0.2).abs() < 1e-9,
        "{report}"
    );
    for k in 1..=3 {
        assert!(stdout.contains(&format!("start {k} at")), "{stdout}");
    }
    assert!(stdout.contains("self-check: "), "{stdout}");
    let served_starts = starts.iter().filter(|s| s["accepted"] == true).count();
    assert_eq!(check["served"].as_u64(), Some(served_starts as u64));
    assert!(starts
        .iter()
        .all(|s| ["precise", "coarse", "refused"].contains(&s["grade"].as_str().unwrap())));
    assert_eq!(served(&out), check["agree"] == true && served_starts > 0);
    let optima = &report["quality"]["optima"];
    assert!(optima["starts"].as_u64().unwrap() >= 6, "{report}");
    for o in optima["found"].as_array().unwrap() {
        let (d, se, z) = (
            o["delta_mi"].as_f64().unwrap(),
            o["se"].as_f64().unwrap(),
            o["z"].as_f64().unwrap(),
        );
        assert!(
            (d / se - z).abs() < 1e-9 && o["separated"] == (z > 2.0),
            "{o}"
        );
    }
    let (ok, err) = refine(dir, &["--starts", "2", "--start-spread", "xy=-1"]);
    assert!(
        !ok && err.trim().lines().count() == 1 && err.contains("--start-spread"),
        "{err}"
    );
    let (ok, err) = refine(dir, &["--starts", "0"]);
    assert!(!ok && err.contains("--starts 0"), "{err}");
}

fn refine_args(args: &[String]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_infraloc"))
        .arg("refine")
        .args(args)
        .output()
        .unwrap()
}

/// One line on stderr, non-zero exit, no pose: what every bad pooled input must give.
fn assert_one_line_failure(out: &std::process::Output, pose: &Path, needle: &str) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "succeeded: {err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(err.contains(needle), "{err}");
    assert!(!pose.exists(), "a pose was written");
}

#[test]
fn refine_cli_pools_pairs_and_refuses_bad_pools() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let truth = write_scene(d);
    let s = |p: &str| d.join(p).display().to_string();
    let out_pose = d.join("pooled.json");
    let base = |extra: &[&str]| -> Vec<String> {
        let mut v: Vec<String> = vec![
            "--camera".into(),
            s("camera.yaml"),
            "--init".into(),
            s("init.json"),
            "--out".into(),
            out_pose.display().to_string(),
            "--report".into(),
            s("pooled-report.json"),
            "--search".into(),
            "x=0.16:0.02,y=0.16:0.02,z=0.1:0.02,yaw=0.6:0.05".into(),
        ];
        v.extend(extra.iter().map(|e| e.to_string()));
        v
    };
    // Two pairs: the same frame, and a second exposure of it (darker, lower contrast) with its
    // own copy of the points. They pool into one histogram per pose.
    let img = image::open(d.join("frame.png")).unwrap().to_luma8();
    let dark = image::GrayImage::from_fn(img.width(), img.height(), |u, v| {
        image::Luma([(img.get_pixel(u, v)[0] as f64 * 0.55 + 20.0) as u8])
    });
    dark.save(d.join("dark.png")).unwrap();
    std::fs::copy(d.join("points.csv"), d.join("points2.csv")).unwrap();
    let ok = refine_args(&base(&[
        "--image",
        &s("frame.png"),
        "--points",
        &s("points.csv"),
        "--image",
        &s("dark.png"),
        "--points",
        &s("points2.csv"),
    ]));
    assert!(
        ok.status.success(),
        "{}",
        String::from_utf8_lossy(&ok.stderr)
    );
    let stdout = String::from_utf8_lossy(&ok.stdout);
    assert!(stdout.contains("(2 pairs pooled)"), "{stdout}");
    assert!(stdout.contains("uncertainty: σ x"), "{stdout}");
    let rep: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("pooled-report.json")).unwrap())
            .unwrap();
    assert_eq!(rep["pairs"], 2);
    let pair_points = rep["pair_points"].as_array().unwrap();
    assert_eq!(pair_points.len(), 2);
    assert_eq!(
        rep["points_used"].as_u64().unwrap(),
        pair_points
            .iter()
            .map(|p| p[1].as_u64().unwrap())
            .sum::<u64>()
    );
    // The pose file carries σ and the covariance; the truth lies within 3σ on each axis.
    let pose: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out_pose).unwrap()).unwrap();
    let q = &pose["quality"];
    let cov = q["covariance"]["matrix"].as_array().unwrap();
    assert_eq!(cov.len(), 4);
    let got = read_pose(&out_pose).unwrap().pose;
    let d_c = got.center() - truth.center();
    for (axis, err) in [("x", d_c.x), ("y", d_c.y), ("z", d_c.z)] {
        let sigma = q["sigma"][axis].as_f64().unwrap();
        assert!(
            sigma > 0.0 && err.abs() <= 3.0 * sigma + 0.01,
            "{axis}: {err} vs σ {sigma}"
        );
    }
    // The written pose, covariance and all, is what `plot mi-surface --pose` reads: it draws the
    // surface through it on the same pairs, with the covariance's ellipse.
    let plot = Command::new(env!("CARGO_BIN_EXE_infraloc"))
        .args(["plot", "mi-surface", "--camera", &s("camera.yaml")])
        .args(["--image", &s("frame.png"), "--points", &s("points.csv")])
        .args(["--image", &s("dark.png"), "--points", &s("points2.csv")])
        .args(["--pose", &out_pose.display().to_string()])
        .args([
            "--search",
            "x=0.16:0.02,y=0.16:0.02,z=0.1:0.02,yaw=0.6:0.05",
        ])
        .args(["--out", &s("surface.png")])
        .output()
        .unwrap();
    assert!(
        plot.status.success(),
        "plot on the written pose: {}",
        String::from_utf8_lossy(&plot.stderr)
    );
    assert!(image::open(d.join("surface.png")).is_ok());
    // Unequal pairs: one line naming both counts, no picture.
    let plot = Command::new(env!("CARGO_BIN_EXE_infraloc"))
        .args(["plot", "mi-surface", "--camera", &s("camera.yaml")])
        .args(["--image", &s("frame.png"), "--image", &s("dark.png")])
        .args(["--points", &s("points.csv")])
        .args(["--pose", &out_pose.display().to_string()])
        .args(["--out", &s("unequal.png")])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&plot.stderr);
    assert!(!plot.status.success() && err.lines().count() == 1, "{err}");
    assert!(err.contains("got 2 and 1"), "{err}");
    assert!(!d.join("unequal.png").exists());
    std::fs::remove_file(&out_pose).unwrap();

    // Unequal counts of --image and --points: refused before anything is read.
    let bad = refine_args(&base(&[
        "--image",
        &s("frame.png"),
        "--image",
        &s("dark.png"),
        "--points",
        &s("points.csv"),
    ]));
    assert_one_line_failure(
        &bad,
        &out_pose,
        "--image given 2 times but --points 1 times",
    );

    // Images of different sizes for one camera.
    image::GrayImage::new(160, 160)
        .save(d.join("small.png"))
        .unwrap();
    let bad = refine_args(&base(&[
        "--image",
        &s("frame.png"),
        "--points",
        &s("points.csv"),
        "--image",
        &s("small.png"),
        "--points",
        &s("points2.csv"),
    ]));
    assert_one_line_failure(&bad, &out_pose, "small.png");

    // A pair whose points all fall outside its image (200 m above the downward camera).
    std::fs::write(
        d.join("far.csv"),
        "x,y,z,reflectivity\n500010,4400020,406,10\n500011,4400020,406,200\n",
    )
    .unwrap();
    let bad = refine_args(&base(&[
        "--image",
        &s("frame.png"),
        "--points",
        &s("points.csv"),
        "--image",
        &s("dark.png"),
        "--points",
        &s("far.csv"),
    ]));
    assert_one_line_failure(&bad, &out_pose, "pair 2 of 2: points: none is visible");
}
