//! `infraloc validate` through the real binary, and the shipped example config.

use std::process::Command;

fn infraloc(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_infraloc"))
        .args(args)
        .output()
        .expect("run infraloc")
}

const EXAMPLE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/config/infraloc.toml");

#[test]
fn shipped_config_validates() {
    // Its keys are valid anywhere …
    let out = infraloc(&["validate", "--keys-only", "--config", EXAMPLE]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(String::from_utf8_lossy(&out.stdout).trim(), "config OK");
    // … but the files it names exist only on an installed node: off one, each missing one is
    // its own line naming the key (the devices and state directory only warn).
    if std::path::Path::new("/etc/infraloc/camera.yaml").exists() {
        eprintln!("skipped the off-node half: /etc/infraloc/camera.yaml exists here");
        return;
    }
    let out = infraloc(&["validate", "--config", EXAMPLE]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(78), "{err}");
    assert!(
        err.lines()
            .any(|l| l.contains("[camera] intrinsics-file /etc/infraloc/camera.yaml")),
        "{err}"
    );
}

#[test]
fn shipped_config_documents_every_key() {
    // Serialise a fully populated config; every key it has must appear in the example file
    // (as a setting or commented out), so a new key cannot ship undocumented.
    let text = std::fs::read_to_string(EXAMPLE).unwrap();
    let mut cfg = infraloc::config::Config::default();
    cfg.camera.intrinsics = Some(infraloc::camera::Camera::Mei(infraloc::camera::Mei {
        fov_deg: Some(185.0),
        ..infraloc::camera::Mei::pinhole(1, 1, 1.0, 1.0, 0.0, 0.0)
    }));
    cfg.camera.intrinsics_file = Some("x".into());
    cfg.camera.frames = Some("x".into());
    cfg.camera.device = Some("x".into());
    cfg.gps.path = Some("x".into());
    cfg.gps.device = Some("x".into());
    cfg.gps.fallback_wgs84 = Some([0.0, 0.0]);
    cfg.output.report = Some("x".into());
    cfg.output.overlay = Some("x".into());
    cfg.init.matcher_path = Some("x".into());
    let table: toml::Table = toml::from_str(&toml::to_string(&cfg).unwrap()).unwrap();
    fn walk(prefix: &str, t: &toml::Table, text: &str, missing: &mut Vec<String>) {
        for (k, v) in t {
            let path = format!("{prefix}{k}");
            match v {
                toml::Value::Table(sub) => {
                    if !text.contains(&format!("[{path}]")) {
                        missing.push(format!("[{path}]"));
                    }
                    walk(&format!("{path}."), sub, text, missing)
                }
                _ => {
                    if !text.lines().any(|l| {
                        l.trim_start_matches(['#', ' '])
                            .starts_with(&format!("{k} ="))
                    }) {
                        missing.push(path)
                    }
                }
            }
        }
    }
    let mut missing = Vec::new();
    walk("", &table, &text, &mut missing);
    assert!(
        missing.is_empty(),
        "config/infraloc.toml does not document: {missing:?}"
    );
}

#[test]
fn bad_config_exits_78_with_one_line_naming_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("bad.toml");
    std::fs::write(&p, "[camera]\nframe-count = \"five\"\n").unwrap();
    let out = infraloc(&["validate", "--config", p.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(78));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.contains("bad.toml") && err.contains("line 2"), "{err}");
    // A semantic gap, not a syntax error: the match-file matcher without its file.
    let shipped =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/config/infraloc.toml"))
            .unwrap();
    // The shipped config with one setting changed, validated on its keys alone (the shipped
    // config's files exist only on a node): the exit code and stderr.
    let validate_edited = |from: &str, to: &str| -> (Option<i32>, String) {
        let edited = shipped.replace(from, to);
        assert_ne!(edited, shipped, "{from} is not in the shipped config");
        std::fs::write(&p, edited).unwrap();
        let out = infraloc(&["validate", "--keys-only", "--config", p.to_str().unwrap()]);
        (
            out.status.code(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    let (code, err) = validate_edited("matcher = \"dense-sweep\"", "matcher = \"match-file\"");
    assert_eq!(code, Some(78), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(
        err.contains("[init]") && err.contains("matcher-path"),
        "{err}"
    );
    // An estimator the refinement does not have: one line naming the value and where it is.
    let (code, err) = validate_edited("sampling = \"pv\"", "sampling = \"bspline\"");
    assert_eq!(code, Some(78), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.contains("bspline") && err.contains("bad.toml"), "{err}");
    // The nearest-pixel local stage is a valid choice beside the default partial volume.
    let (code, err) = validate_edited("sampling = \"pv\"", "sampling = \"nearest\"");
    assert_eq!(code, Some(0), "{err}");
    let missing = infraloc(&["validate", "--config", "/nonexistent/infraloc.toml"]);
    assert_eq!(missing.status.code(), Some(78));
    assert!(String::from_utf8_lossy(&missing.stderr).contains("/nonexistent/infraloc.toml"));
}
