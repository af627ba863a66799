//! The service's georeferencing, for real: the `infraloc daemon` binary on a simulated scene,
//! asked through `infraloc georef --running` and the raw control socket, its lookup table read
//! back by numpy (python3 with numpy is required, as for the other reference tests: .ci/setup).
//!
//! The served pose is the scene's truth stored as the pose file, with a covariance; the camera is
//! an absent v4l2 device, so the boot localization fails at once and the stored pose stays
//! served. The lookup table's rewrite is then checked by serving a new pose (a working camera,
//! SIGHUP, `relocalize --wait --force`): one real localization.

use infraloc::control::{Client, Request, MAX_GEOREF_PIXELS};
use infraloc::posefile::PoseFile;
use serde_json::{json, Value};
use std::os::unix::fs::MetadataExt;
use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use crate::common;
use crate::common::served::{
    cli, grid_1000, raw, set, store_truth, text, write_config, Daemon, BIN, SCENE, STORED_AT,
};
use std::io::Write;

fn json_of(out: &Output) -> Value {
    assert!(out.status.success(), "{}", text(&out.stderr));
    serde_json::from_slice(&out.stdout).unwrap()
}

/// A one-line error and exit 1 that contains `want`.
fn fails_with(out: &Output, want: &str) {
    let e = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{e}");
    assert!(e.contains(want) && e.trim_end().lines().count() == 1, "{e}");
    assert!(out.stdout.is_empty());
}

fn lut_meta(work: &Path) -> Option<Value> {
    let t = std::fs::read_to_string(work.join("georef_lut.json")).ok()?;
    serde_json::from_str(&t).ok()
}

/// Wait until the lookup table's description names the pose from `at`.
fn wait_lut(d: &mut Daemon, work: &Path, at: &str) -> Value {
    let start = Instant::now();
    loop {
        if let Some(m) = lut_meta(work) {
            if m["pose"]["timestamp_utc"] == at {
                return m;
            }
        }
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "no lookup table for the pose from {at}: {:?}; {}",
            lut_meta(work),
            d.log()
        );
        if let Ok(Some(st)) = d.child.try_wait() {
            panic!("daemon exited ({st}): {}", d.log());
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// numpy's view of the table: its shape, then the four channels of each cell (row, col).
fn numpy_cells(npy: &Path, cells: &[(usize, usize)]) -> (Vec<usize>, Vec<[f64; 4]>) {
    const READ: &str = r#"
import sys, numpy as np
a = np.load(sys.argv[1])
assert a.dtype == np.float64, a.dtype
print(*a.shape)
for line in sys.stdin:
    r, c = map(int, line.split())
    print(*(repr(float(x)) for x in a[r, c]))
"#;
    let mut child = Command::new("python3")
        .args(["-c", READ])
        .arg(npy)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("python3 with numpy is needed: see .ci/setup");
    let q: String = cells.iter().map(|(r, c)| format!("{r} {c}\n")).collect();
    child.stdin.take().unwrap().write_all(q.as_bytes()).unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "numpy: {}", text(&out.stderr));
    let t = text(&out.stdout);
    let mut lines = t.lines();
    let shape = lines
        .next()
        .unwrap()
        .split(' ')
        .map(|s| s.parse().unwrap())
        .collect();
    let vals = lines
        .map(|l| {
            let v: Vec<f64> = l.split(' ').map(|s| s.parse().unwrap()).collect();
            [v[0], v[1], v[2], v[3]]
        })
        .collect();
    (shape, vals)
}

fn csv(pixels: &[[f64; 2]]) -> String {
    pixels
        .iter()
        .map(|p| format!("{},{}\n", p[0], p[1]))
        .collect()
}

#[test]
fn georef_request_and_lookup_table_follow_the_served_pose() {
    let tmp = tempfile::tempdir().unwrap();
    let (scene, work) = (tmp.path().join("scene"), tmp.path().join("work"));
    common::simulate(BIN, &scene, &SCENE);
    std::fs::create_dir(&work).unwrap();
    let cfg = write_config(&scene, &work, false);
    store_truth(&scene, &work);
    let socket = work.join("run/control.sock");
    let mut d = Daemon::start(&cfg);
    // The boot localization fails (no camera); the stored pose stays served.
    d.wait_status(&cfg, |v| !v["last_result"].is_null());
    let meta = wait_lut(&mut d, &work, STORED_AT);

    // The control points' true pixels, a NaN pixel and one off the sensor.
    let truth: Value =
        serde_json::from_str(&std::fs::read_to_string(scene.join("truth.json")).unwrap()).unwrap();
    let cps = truth["control_points"].as_array().unwrap();
    let mut pixels: Vec<[f64; 2]> = cps
        .iter()
        .map(|c| {
            [
                c["pixel"][0].as_f64().unwrap(),
                c["pixel"][1].as_f64().unwrap(),
            ]
        })
        .collect();
    let n_cp = pixels.len();
    assert!(n_cp > 20, "{n_cp} control points");
    pixels.push([f64::NAN, 5.0]);
    pixels.push([-10.0, -10.0]);

    let served = json_of(&cli(
        &cfg,
        &["georef", "--running", "--format", "json"],
        &csv(&pixels),
    ));
    assert_eq!(served["schema"], "infraloc.georef.v1");
    assert_eq!(
        served["pose"]["timestamp_utc"], STORED_AT,
        "{}",
        served["pose"]
    );
    assert_eq!(served["pose"]["sigma"]["yaw"], 0.05);
    assert_eq!(served["pose"]["covariance"], true);
    let pts = served["points"].as_array().unwrap();
    assert_eq!(pts.len(), pixels.len());
    assert_eq!(pts[n_cp]["status"], "non_finite");
    assert!(pts[n_cp]["u"].is_null());
    assert_eq!(pts[n_cp + 1]["status"], "outside_image");
    // The same pixels through the files (the served pose file, the tile on disk) agree, and the
    // ground points lie where the control points are.
    let local = json_of(&cli(&cfg, &["georef", "--format", "json"], &csv(&pixels)));
    let (mut ok, mut errs) = (0, Vec::new());
    for (k, (a, b)) in pts
        .iter()
        .zip(local["points"].as_array().unwrap())
        .enumerate()
    {
        assert_eq!(a["status"], b["status"], "pixel {k}");
        if a["status"] != "ok" {
            continue;
        }
        ok += 1;
        for key in ["e", "n", "h", "sigma_major_m"] {
            let (x, y) = (a[key].as_f64().unwrap(), b[key].as_f64().unwrap());
            assert!((x - y).abs() < 1e-6, "pixel {k} {key}: {x} vs {y}");
        }
        if k < n_cp {
            let m = &cps[k]["map"];
            let de = a["e"].as_f64().unwrap() - m[0].as_f64().unwrap();
            let dn = a["n"].as_f64().unwrap() - m[1].as_f64().unwrap();
            // The truth pose with the scene's calibrated (slightly wrong) intrinsics: a few cm
            // near the pole, growing with the range.
            let range = a["range_m"].as_f64().unwrap();
            assert!(
                de.hypot(dn) < 0.05 + 0.02 * range,
                "control point {k} at {range:.1} m: {de:.3}, {dn:.3} m"
            );
            errs.push(de.hypot(dn));
            assert!(a["sigma_major_m"].as_f64().unwrap() > 0.009);
        }
    }
    assert!(ok > n_cp / 2, "{ok} of {n_cp} control points ok");
    errs.sort_by(f64::total_cmp);
    assert!(
        errs[errs.len() / 2] < 0.05,
        "median error {:.3} m",
        errs[errs.len() / 2]
    );
    // CSV through the service reads as the local CSV.
    let a = cli(&cfg, &["georef", "--running"], &csv(&pixels));
    let b = cli(&cfg, &["georef"], &csv(&pixels));
    assert!(a.status.success(), "{}", text(&a.stderr));
    let (a, b) = (text(&a.stdout), text(&b.stdout));
    assert_eq!(a.lines().count(), pixels.len() + 1);
    for (la, lb) in a.lines().zip(b.lines()) {
        let fa: Vec<&str> = la.split(',').collect();
        let fb: Vec<&str> = lb.split(',').collect();
        assert_eq!(fa[..3], fb[..3]);
        for i in 3..6 {
            if let (Ok(x), Ok(y)) = (fa[i].parse::<f64>(), fb[i].parse::<f64>()) {
                assert!((x - y).abs() <= 1e-4 + 1e-9, "{la} vs {lb}");
            }
        }
    }

    // Bad batches: one-line refusals; the service keeps serving.
    fails_with(
        &cli(&cfg, &["georef", "--running"], ""),
        "the batch has no pixels",
    );
    let over = csv(&vec![[500.0, 500.0]; MAX_GEOREF_PIXELS + 1]);
    fails_with(
        &cli(&cfg, &["georef", "--running"], &over),
        "10001 pixels, more than the 10000 one request may carry",
    );
    fails_with(
        &cli(&cfg, &["georef", "--running"], "1,2\n1,x\n"),
        "line 2: v is not a number",
    );
    fails_with(
        &cli(&cfg, &["georef", "--running", "--sigma-px=-1"], "1,2\n"),
        "--sigma-px",
    );
    let v = raw(&socket, &json!({"request": "georef", "pixels": [["a", 1]]}));
    assert_eq!(v["ok"], false);
    assert!(
        v["error"].as_str().unwrap().starts_with("bad request"),
        "{v}"
    );
    let v = raw(
        &socket,
        &json!({"request": "georef", "pixels": [[500, 500]], "sigma_px": -1}),
    );
    assert_eq!(v["ok"], false);
    assert!(v["error"].as_str().unwrap().contains("sigma_px"), "{v}");
    let v = raw(
        &socket,
        &json!({"request": "georef", "pixels": [[500, 500]], "height_sigma_m": -0.1}),
    );
    assert_eq!(v["ok"], false);
    assert_eq!(
        v["error"], "georef: height_sigma_m -0.1: must be a finite number ≥ 0",
        "{v}"
    );
    // The answer names its surface: the smoothing and the height σ estimated from the layer
    // (the simulator's 3 cm, within the estimator's spread) or the one asked for.
    let v = raw(
        &socket,
        &json!({"request": "georef", "pixels": [[500, 500]]}),
    );
    assert_eq!(v["surface"]["smoothing_m"], 0.15, "{v}");
    let est = v["surface"]["height_sigma_m"].as_f64().unwrap();
    assert!((0.025..0.035).contains(&est), "{v}");
    let v = raw(
        &socket,
        &json!({"request": "georef", "pixels": [[500, 500]], "height_sigma_m": 0.01}),
    );
    assert_eq!(v["surface"]["height_sigma_m"], 0.01, "{v}");
    let v = raw(
        &socket,
        &json!({"request": "georef", "pixels": [[1e300, null]]}),
    );
    assert_eq!(v["ok"], true, "{v}");
    assert_eq!(v["points"][0]["status"], "non_finite");
    let v = raw(&socket, &json!({"request": "status"}));
    assert_eq!(v["ok"], true, "the service stopped serving: {v}");

    // A 1,000-pixel request through the client (its latency: benches/georef_socket.rs): a 40 × 25
    // grid over the image, every pixel answered in order.
    let (w, h) = (
        meta["image_width"].as_f64().unwrap(),
        meta["image_height"].as_f64().unwrap(),
    );
    let grid = grid_1000(w, h);
    let req = Request::Georef {
        pixels: grid.clone(),
        sigma_px: 0.0,
        height_sigma_m: None,
    };
    let a = Client::connect(&socket)
        .unwrap()
        .call(&req, Duration::from_secs(30), |_| {})
        .unwrap();
    assert_eq!(a.refusal(), None);
    let v: Value = a.parse("georef answer").unwrap();
    let points = v["points"].as_array().unwrap();
    assert_eq!(points.len(), 1000);
    for (p, px) in points.iter().zip(&grid) {
        assert_eq!(p["u"].as_f64(), px[0], "{p}");
        assert_eq!(p["v"].as_f64(), px[1], "{p}");
    }

    // The lookup table: its layout, numpy's reading, and each cell = the pixel's georeference.
    let step = meta["step_px"].as_u64().unwrap() as usize;
    assert_eq!(step, 4);
    let (rows, cols) = ((h as usize).div_ceil(4), (w as usize).div_ceil(4));
    assert_eq!(meta["shape"], json!([rows, cols, 4]));
    assert_eq!(meta["channels"], json!(["e", "n", "h", "sigma_major_m"]));
    let cells: Vec<(usize, usize)> = (0..60)
        .map(|k| (rows / 2 + k % 7 * 5 - 15, cols / 2 + k * 3 - 90))
        .collect();
    let npy = work.join("georef_lut.npy");
    let (shape, vals) = numpy_cells(&npy, &cells);
    assert_eq!(shape, vec![rows, cols, 4]);
    let px: Vec<[f64; 2]> = cells
        .iter()
        .map(|&(r, c)| [(c * 4) as f64, (r * 4) as f64])
        .collect();
    let want = json_of(&cli(
        &cfg,
        &["georef", "--running", "--format", "json"],
        &csv(&px),
    ));
    let mut ok = 0;
    for (k, (got, w)) in vals
        .iter()
        .zip(want["points"].as_array().unwrap())
        .enumerate()
    {
        if w["status"] == "ok" {
            ok += 1;
            for (i, key) in ["e", "n", "h", "sigma_major_m"].iter().enumerate() {
                let x = w[key].as_f64().unwrap();
                assert!(
                    (got[i] - x).abs() < 1e-9,
                    "cell {:?} {key}: {} vs {x}",
                    cells[k],
                    got[i]
                );
            }
        } else {
            assert!(
                got.iter().all(|v| v.is_nan()),
                "cell {:?}: {got:?}",
                cells[k]
            );
        }
    }
    assert!(ok > 40, "{ok} of 60 cells near the image centre ok");
    let ino = std::fs::metadata(&npy).unwrap().ino();

    // A new served pose rewrites the table (atomically: a new file renamed over the old) and is
    // the one the request names.
    let cfg = write_config(&scene, &work, true);
    let hup = Command::new("kill")
        .args(["-HUP", &d.child.id().to_string()])
        .status()
        .unwrap();
    assert!(hup.success());
    d.wait_status(&cfg, |_| d_log_has(&work, "config reloaded"));
    let out = cli(&cfg, &["relocalize", "--wait", "--force"], "");
    assert!(out.status.success(), "{}; {}", text(&out.stderr), d.log());
    let new: PoseFile =
        serde_json::from_str(&std::fs::read_to_string(work.join("pose.json")).unwrap()).unwrap();
    assert_ne!(new.timestamp_utc, STORED_AT);
    wait_lut(&mut d, &work, &new.timestamp_utc);
    assert_ne!(
        std::fs::metadata(&npy).unwrap().ino(),
        ino,
        "rewritten in place"
    );
    let (shape, _) = numpy_cells(&npy, &[]);
    assert_eq!(shape, vec![rows, cols, 4]);
    let again = json_of(&cli(
        &cfg,
        &["georef", "--running", "--format", "json"],
        &csv(&pixels[..3]),
    ));
    assert_eq!(again["pose"]["timestamp_utc"], new.timestamp_utc.as_str());
    let leftovers: Vec<String> = std::fs::read_dir(&work)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains(".tmp."))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
}

fn d_log_has(work: &Path, what: &str) -> bool {
    std::fs::read_to_string(work.join("daemon.log")).is_ok_and(|l| l.contains(what))
}

#[test]
fn without_a_served_pose_georef_is_refused_and_no_table_written() {
    let tmp = tempfile::tempdir().unwrap();
    let (scene, work) = (tmp.path().join("scene"), tmp.path().join("work"));
    common::simulate(BIN, &scene, &SCENE);
    std::fs::create_dir(&work).unwrap();
    let cfg = write_config(&scene, &work, false);
    let mut d = Daemon::start(&cfg);
    d.wait_status(&cfg, |v| v["state"] == "failed");
    fails_with(
        &cli(&cfg, &["georef", "--running"], "500,500\n"),
        "no pose served yet",
    );
    assert!(!work.join("georef_lut.npy").exists());
    assert!(!work.join("georef_lut.json").exists());

    // A lookup-table step out of range is a config error (78) naming the key.
    let mut t: toml::Table = toml::from_str(&std::fs::read_to_string(&cfg).unwrap()).unwrap();
    set(&mut t, "output", "georef-lut-step-px", 65);
    std::fs::write(&cfg, toml::to_string(&t).unwrap()).unwrap();
    let out = Command::new(BIN)
        .args(["validate", "--keys-only", "--config"])
        .arg(&cfg)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(78), "{}", text(&out.stderr));
    assert!(
        text(&out.stderr).contains("[output] georef-lut-step-px = 65 is out of range: use 0 to 64"),
        "{}",
        text(&out.stderr)
    );
}
