//! `infraloc localize` serving the initializer's own pose when the refinement is refused (issue
//! 65, "the node serves what it knows"): on a simulated `hard` scene whose refinement is made to
//! refuse (a `min-points` above any fixed set, a reason about its evidence and not its place),
//! the PnP pose is written graded coarse with the initializer's σ, says where it came from and
//! why, exits 5, and covers the truth within 3σ on x, y, z and yaw.

use crate::common;
use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_infraloc");

fn json(path: &std::path::Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

#[test]
fn a_refused_refinement_serves_the_initializer_s_pose_coarse() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    common::simulate(
        BIN,
        dir,
        &["--seed", "1", "--preset", "small", "--difficulty", "hard"],
    );
    let cfg = std::fs::read_to_string(dir.join("infraloc.toml")).unwrap();
    assert!(
        cfg.contains("\nmin-points = 1000\n"),
        "the scene's config changed: {cfg}"
    );
    let strict = dir.join("strict.toml");
    std::fs::write(
        &strict,
        cfg.replace("\nmin-points = 1000\n", "\nmin-points = 100000000\n"),
    )
    .unwrap();

    let out = Command::new(BIN)
        .arg("localize")
        .arg("--config")
        .arg(&strict)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(
        out.status.code(),
        Some(5),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("the initializer's pose"), "{stdout}");

    let pose = json(&dir.join("pose.json"));
    let q = &pose["quality"];
    assert_eq!(q["grade"], "coarse", "{q}");
    assert_eq!(q["source"], "initializer", "{q}");
    let why = q["refinement_refused"].as_str().unwrap();
    assert!(
        why.contains("points seen") && why.contains("100000000"),
        "{why}"
    );
    // The orthophoto's registration (0.3 m by default) is part of x's and y's σ.
    let sigma = |a: &str| q["sigma"][a].as_f64().unwrap();
    assert!(sigma("x") >= 0.3 && sigma("y") >= 0.3, "{q}");

    let truth = json(&dir.join("truth.json"));
    let c = |v: &serde_json::Value, k: usize| v["camera_center"][k].as_f64().unwrap();
    for (k, a) in ["x", "y", "z"].iter().enumerate() {
        let e = c(&pose, k) - c(&truth, k);
        assert!(
            e.abs() <= 3.0 * sigma(a),
            "{a}: error {e} m, σ {}",
            sigma(a)
        );
    }
    let yaw = |v: &serde_json::Value| v["yaw_pitch_roll_deg"][0].as_f64().unwrap();
    let dyaw = (yaw(&pose) - yaw(&truth) + 540.0).rem_euclid(360.0) - 180.0;
    assert!(
        dyaw.abs() <= 3.0 * sigma("yaw"),
        "yaw: error {dyaw}°, σ {}",
        sigma("yaw")
    );
}
