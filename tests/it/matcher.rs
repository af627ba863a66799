//! The initialization's matcher seam (issue 4, "a `Matcher` trait so a learned matcher can be
//! plugged in"): `[init] matcher = "match-file"` replaces the satellite matching with
//! correspondences made elsewhere, through the real binary on a simulated `hard` scene. The file
//! here is what an offline matcher would hand over: the scene's control points (fisheye pixel ↔
//! map point) with pixel noise, a third of them without a height, and 40 % outliers.

use crate::common;

use rand::{Rng, SeedableRng};
use std::io::Write;
use std::path::Path;

const BIN: &str = env!("CARGO_BIN_EXE_infraloc");

fn simulate(dir: &Path) {
    common::simulate(
        BIN,
        dir,
        &["--seed", "5", "--preset", "small", "--difficulty", "hard"],
    );
}

/// `matches.csv` from the truth's control points: `outliers` of every 5 rows get a map point
/// 3–20 m away; every third row leaves z empty (the height layer supplies it).
fn write_matches(dir: &Path, outliers_per_5: usize) {
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("truth.json")).unwrap()).unwrap();
    let cps = truth["control_points"].as_array().unwrap();
    assert!(
        cps.len() >= 30,
        "scene has only {} control points",
        cps.len()
    );
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
    let mut f = std::fs::File::create(dir.join("matches.csv")).unwrap();
    writeln!(f, "u,v,x,y,z").unwrap();
    for (i, c) in cps.iter().enumerate() {
        let m: Vec<f64> = serde_json::from_value(c["map"].clone()).unwrap();
        let p: Vec<f64> = serde_json::from_value(c["pixel"].clone()).unwrap();
        let (mut x, mut y) = (m[0], m[1]);
        if i % 5 < outliers_per_5 {
            let (r, a) = (
                rng.random_range(3.0..20.0),
                rng.random_range(0.0..std::f64::consts::TAU),
            );
            x += r * a.cos();
            y += r * a.sin();
        }
        let z = if i % 3 == 0 {
            String::new()
        } else {
            format!("{:.3}", m[2])
        };
        let (u, v) = (
            p[0] + rng.random_range(-0.7..0.7),
            p[1] + rng.random_range(-0.7..0.7),
        );
        writeln!(f, "{u:.3},{v:.3},{x:.3},{y:.3},{z}").unwrap();
    }
}

fn use_match_file(dir: &Path) {
    let path = dir.join("infraloc.toml");
    let mut cfg: toml::Table = std::fs::read_to_string(&path).unwrap().parse().unwrap();
    let mut init = toml::Table::new();
    init.insert("matcher".into(), "match-file".into());
    init.insert("matcher-path".into(), "matches.csv".into());
    cfg.insert("init".into(), init.into());
    std::fs::write(&path, toml::to_string(&cfg).unwrap()).unwrap();
}

#[test]
fn a_match_file_replaces_the_satellite_matching() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    simulate(dir);
    write_matches(dir, 2);
    use_match_file(dir);
    let out = common::localize_scene(BIN, dir, true);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap()).unwrap();
    let pnp = &r["stages"][1];
    assert_eq!(pnp["name"], "pnp");
    assert_eq!(pnp["detail"]["matcher"], "match-file");
    let err = |stage: &str, k: &str| r["truth"][stage][k].as_f64().unwrap();
    eprintln!("pnp {} / mi {}", r["truth"]["pnp"], r["truth"]["mi"]);
    // The file's pose is a PnP on pixel-noisy control points under `hard`'s wrong intrinsics
    // (measured 5.1 cm, 0.03°, 0.25 px); MI then gives the pipeline's usual accuracy.
    assert!(err("pnp", "horizontal_m") < 0.15 && err("pnp", "yaw_deg") < 0.2);
    assert!(err("pnp", "control_points_mean_px") < 1.0);
    assert!(err("mi", "horizontal_m") < 0.10 && err("mi", "yaw_deg") < 0.2);
    assert!(dir.join("pose.json").exists());
}

#[test]
fn a_useless_or_broken_match_file_fails_in_one_line_and_keeps_the_pose() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    simulate(dir);
    use_match_file(dir);
    let last_good = b"{\"last good\": true}\n";
    let fails = |what: &str| {
        std::fs::write(dir.join("pose.json"), last_good).unwrap();
        let out = common::localize_scene(BIN, dir, true);
        let stderr = String::from_utf8_lossy(&out.stderr).trim().to_string();
        assert!(!out.status.success(), "{what}: succeeded");
        assert_eq!(stderr.lines().count(), 1, "{what}: {stderr}");
        assert_eq!(
            std::fs::read(dir.join("pose.json")).unwrap(),
            last_good,
            "{what}"
        );
        stderr
    };
    // Every row an outlier: no pose agrees with enough of them.
    write_matches(dir, 5);
    let e = fails("all outliers");
    // The stage is named once; the random temporary directory may spell "pnp" too.
    let without_dir = e.replace(&*dir.to_string_lossy(), "");
    assert!(
        e.starts_with("infraloc: pnp: match-file ")
            && e.contains("matches.csv: ")
            && without_dir.matches("pnp").count() == 1,
        "{e}"
    );
    // A file that is not a match file names the file and the line.
    std::fs::write(dir.join("matches.csv"), "u,v,x,y\n1,2,3\n").unwrap();
    let e = fails("short row");
    assert!(
        e.contains("matches.csv") && e.contains("line 2: missing y"),
        "{e}"
    );
    // No file at all.
    std::fs::remove_file(dir.join("matches.csv")).unwrap();
    let e = fails("missing file");
    assert!(e.contains("matches.csv"), "{e}");
}
