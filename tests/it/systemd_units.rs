//! The shipped systemd units pass `systemd-analyze verify` with nothing on stderr, its man check
//! included (every `Documentation=man:` page must open: the pages `infraloc man` writes are put
//! on MANPATH, as the .deb puts them in /usr/share/man), and the service's offline security
//! exposure stays ≤ 2.0.

use crate::common;

use std::path::Path;
use std::process::Command;

const UNITS: [&str; 3] = [
    "infraloc.service",
    "infraloc-relocalize.service",
    "infraloc-relocalize.timer",
];
/// Highest acceptable `systemd-analyze security` exposure for the daemon.
const MAX_EXPOSURE: f64 = 2.0;

/// Copy the units with ExecStart pointing at the freshly built binary (verify checks it exists).
fn staged_units() -> Option<tempfile::TempDir> {
    if Command::new("systemd-analyze")
        .arg("--version")
        .output()
        .is_err()
    {
        common::skip_unless_ci(
            "systemd_units",
            "systemd-analyze not installed (apt-get install systemd; .ci/setup installs it)",
        );
        return None;
    }
    let dir = tempfile::tempdir().unwrap();
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("systemd");
    for u in UNITS {
        let text = std::fs::read_to_string(src.join(u)).unwrap();
        let text = text.replace("/usr/bin/infraloc", env!("CARGO_BIN_EXE_infraloc"));
        std::fs::write(dir.path().join(u), text).unwrap();
    }
    write_man_pages(&dir.path().join("man"));
    Some(dir)
}

/// `infraloc man --out DIR`: the pages the .deb installs, for `systemd-analyze verify`'s man check.
fn write_man_pages(dir: &Path) {
    let out = Command::new(env!("CARGO_BIN_EXE_infraloc"))
        .args(["man", "--out"])
        .arg(dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn units_verify_cleanly() {
    let Some(dir) = staged_units() else { return };
    let out = Command::new("systemd-analyze")
        .arg("verify")
        .args(UNITS.map(|u| format!("./{u}")))
        .current_dir(dir.path())
        .env("MANPATH", dir.path().join("man"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success() && err.trim().is_empty(),
        "systemd-analyze verify:\n{err}"
    );
}

#[test]
fn service_exposure_is_low() {
    let Some(dir) = staged_units() else { return };
    let out = Command::new("systemd-analyze")
        .args(["security", "--offline=true", "./infraloc.service"])
        .current_dir(dir.path())
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    let line = text
        .lines()
        .find(|l| l.contains("Overall exposure level"))
        .unwrap_or_else(|| panic!("no exposure line in:\n{text}"));
    let score: f64 = line
        .split(':')
        .nth(1)
        .and_then(|s| s.split_whitespace().next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("cannot parse {line:?}"));
    assert!(
        score <= MAX_EXPOSURE,
        "exposure {score} > {MAX_EXPOSURE}: {line}"
    );
}
