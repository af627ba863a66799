//! `infraloc demo` through the binary, as a new user runs it (README "Start here"): it must pass
//! on its default scene with the errors it prints under the thresholds the README documents, say
//! nothing on a non-terminal stderr, and print no path that is gone once it exits.

use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_infraloc");

/// The thresholds README.md documents (horizontal m, height m, yaw °). Written out here rather
/// than read from the code, so that loosening the code's constants fails this test.
const DOCUMENTED: [f64; 3] = [0.10, 0.10, 0.2];

/// The (horizontal m, height m, yaw °) errors of `stage`'s row in the demo's table, e.g.
/// `mi          0.032 m    0.057 m   0.071 °          1.06 px      2.16`.
fn row_errors(stdout: &str, stage: &str) -> [f64; 3] {
    let line = stdout
        .lines()
        .find(|l| l.split_whitespace().next() == Some(stage))
        .unwrap_or_else(|| panic!("no {stage} row in:\n{stdout}"));
    let t: Vec<&str> = line.split_whitespace().collect();
    assert_eq!((t[2], t[4], t[6]), ("m", "m", "°"), "{line}");
    [1, 3, 5].map(|i| t[i].parse().unwrap_or_else(|e| panic!("{line}: {e}")))
}

#[test]
fn demo_passes_under_the_documented_thresholds() {
    let tmp = tempfile::tempdir().unwrap();
    let overlay = tmp.path().join("ov.png");
    let out = Command::new(BIN)
        .arg("demo")
        .arg("--overlay")
        .arg(&overlay)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stdout}\n{stderr}");
    // stderr is a pipe here: no progress line, no other output.
    assert!(stderr.is_empty(), "{stderr:?}");

    let mi = row_errors(&stdout, "mi");
    for ((name, e), max) in ["horizontal", "height", "yaw"]
        .iter()
        .zip(mi)
        .zip(DOCUMENTED)
    {
        assert!(e < max, "mi {name} error {e} ≥ documented {max}:\n{stdout}");
    }
    // The PnP row is printed too; only the final pose is judged.
    assert!(row_errors(&stdout, "pnp").iter().all(|e| e.is_finite()));
    assert!(stdout.contains("demo OK"), "{stdout}");

    // The scene lived in a temporary directory, now deleted: no line may point into it.
    for word in stdout.split_whitespace().filter(|w| w.starts_with('/')) {
        assert!(
            std::path::Path::new(word).exists(),
            "printed {word}, which does not exist after the demo:\n{stdout}"
        );
    }
    // The picture outlives the scene: both panels (before | after) of the 1024² frame.
    assert!(
        stdout.contains(&format!("overlay: {}", overlay.display())),
        "{stdout}"
    );
    let png = image::open(&overlay).unwrap();
    assert_eq!((png.width(), png.height()), (2 * 1024, 1024));
    assert!(stdout.contains("not kept (--keep DIR"), "{stdout}");
}

#[test]
fn demo_help_states_the_documented_thresholds() {
    let out = Command::new(BIN).args(["demo", "--help"]).output().unwrap();
    let help = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{help}");
    for t in ["0.1 m horizontally", "0.1 m in height", "0.2° in yaw"] {
        assert!(help.contains(t), "{t:?} not in:\n{help}");
    }
    let readme =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/README.md")).unwrap();
    for t in [
        "| horizontal | 0.10 m |",
        "| height | 0.10 m |",
        "| yaw | 0.2° |",
    ] {
        assert!(readme.contains(t), "README lacks {t:?}");
    }
}
