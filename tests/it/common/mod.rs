//! Shared helpers of the integration tests: where the real GNSS logs are, gpsd's `.chk`, the
//! simulated scenes (each simulated once per run), and the served pose of `served`.
#![allow(dead_code, unreachable_pub)]

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock, PoisonError};

pub mod served;

/// `rel` under `shared/data` beside the clone (as CI lays it out); `INFRALOC_SHARED_DATA`
/// overrides the `shared/data` directory for other layouts. Not checked for existence.
pub fn shared_data(rel: &str) -> PathBuf {
    match std::env::var_os("INFRALOC_SHARED_DATA") {
        Some(d) => PathBuf::from(d),
        None => PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data")),
    }
    .join(rel)
}

/// [`shared_data`]`("nmea")`; a missing directory fails the test loudly.
pub fn nmea_dir() -> PathBuf {
    let dir = shared_data("nmea");
    assert!(
        dir.is_dir(),
        "{} missing: set INFRALOC_SHARED_DATA to the shared/data directory",
        dir.display()
    );
    dir
}

/// All `*.log` files, sorted.
pub fn nmea_logs() -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(nmea_dir())
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "log"))
        .collect();
    v.sort();
    v
}

/// One echoed sentence of a `.chk` and the first TPV report gpsd emitted right after it.
pub struct Entry {
    /// The sentence as gpsd echoed it.
    pub sentence: String,
    /// First TPV before the next echoed sentence.
    pub tpv: Option<serde_json::Value>,
}

/// A parsed `.chk` file.
pub struct Reference {
    /// Echoed sentences in order.
    pub entries: Vec<Entry>,
}

impl Reference {
    /// Parse gpsd's `.chk`.
    pub fn load(path: &Path) -> Reference {
        let text = std::fs::read_to_string(path).unwrap();
        let mut entries: Vec<Entry> = Vec::new();
        for line in text.lines() {
            let line = line.trim_end();
            if line.starts_with('$') || line.starts_with('!') {
                entries.push(Entry {
                    sentence: line.to_string(),
                    tpv: None,
                });
            } else if line.starts_with('{') {
                let v: serde_json::Value = serde_json::from_str(line).unwrap();
                if v["class"] == "TPV" {
                    if let Some(e) = entries.last_mut() {
                        e.tpv.get_or_insert(v);
                    }
                }
            }
        }
        Reference { entries }
    }
}

/// `2019-04-12T00:39:56.000Z` → Unix milliseconds.
pub fn iso_to_unix_ms(s: &str) -> i64 {
    let (date, time) = s.trim_end_matches('Z').split_once('T').unwrap();
    let d: Vec<u32> = date.split('-').map(|x| x.parse().unwrap()).collect();
    let (hms, frac) = time.split_once('.').unwrap_or((time, "0"));
    let t: Vec<i64> = hms.split(':').map(|x| x.parse().unwrap()).collect();
    let ms: i64 = format!("{frac:0<3}")[..3].parse().unwrap();
    let days = infraloc::gnss::nmea::Date::new(d[0] as u16, d[1] as u8, d[2] as u8)
        .unwrap()
        .days_since_epoch();
    days * 86_400_000 + (t[0] * 3600 + t[1] * 60 + t[2]) * 1000 + ms
}

/// A scene directory per distinct `simulate` argument list, simulated once per test run and
/// shared by every module that asks for the same preset and seed (a small scene takes ~10 s of
/// the two cores; the modules asked for the same ones several times over).
struct Scenes {
    /// Holds every shared scene; a static is never dropped, so it lasts the whole run.
    root: tempfile::TempDir,
    /// Each argument list's scene, built by the first caller while later ones wait on its cell.
    by_args: Mutex<HashMap<Vec<String>, &'static OnceLock<PathBuf>>>,
}

/// The scene `BIN simulate ARGS` makes, simulated on first use and shared read-only for the rest
/// of the run; a failed simulation fails the test with its stderr. Tests that change files of
/// their scene take their own copy with [`simulate`] instead.
pub fn shared_scene(bin: &str, args: &[&str]) -> &'static Path {
    static SCENES: OnceLock<Scenes> = OnceLock::new();
    let scenes = SCENES.get_or_init(|| Scenes {
        root: tempfile::tempdir().expect("temporary directory for the shared scenes"),
        by_args: Mutex::default(),
    });
    let (index, cell) = {
        // Only map operations run under the lock, so a panicking test cannot poison it midway.
        let mut map = scenes
            .by_args
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        let index = map.len();
        let key = args.iter().map(|a| a.to_string()).collect();
        let cell = *map
            .entry(key)
            .or_insert_with(|| Box::leak(Box::new(OnceLock::new())));
        (index, cell)
    };
    cell.get_or_init(|| {
        let dir = scenes.root.path().join(format!("scene-{index}"));
        let out = std::process::Command::new(bin)
            .arg("simulate")
            .args(args)
            .arg("--out")
            .arg(&dir)
            .output()
            .expect("run infraloc simulate");
        assert!(
            out.status.success(),
            "simulate {args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        dir
    })
}

/// The scene `BIN simulate ARGS --out DIR` makes (the scene the localize tests start from), as a
/// copy of [`shared_scene`] that the test may change; a failed simulation fails the test with its
/// stderr. The simulator's output does not depend on its directory (`simulate_cli` checks two
/// runs byte for byte), so the copy is what simulating into `dir` would have written.
pub fn simulate(bin: &str, dir: &Path, args: &[&str]) {
    copy_tree(shared_scene(bin, args), dir);
}

/// Every file under `dir` with its bytes, by path relative to `dir`.
pub fn tree_files(dir: &Path) -> std::collections::BTreeMap<PathBuf, Vec<u8>> {
    let mut out = std::collections::BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap_or_else(|e| panic!("{}: {e}", d.display())) {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let bytes = std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
                out.insert(p.strip_prefix(dir).unwrap().to_path_buf(), bytes);
            }
        }
    }
    out
}

/// Copy the directory tree `from` to `to` (created, with its parents).
pub fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap_or_else(|e| panic!("{}: {e}", to.display()));
    for e in std::fs::read_dir(from).unwrap_or_else(|e| panic!("{}: {e}", from.display())) {
        let e = e.unwrap();
        let dest = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_tree(&e.path(), &dest);
        } else {
            std::fs::copy(e.path(), &dest)
                .unwrap_or_else(|err| panic!("{} → {}: {err}", e.path().display(), dest.display()));
        }
    }
}

/// Run `BIN localize` on a simulated scene in `dir` (its `infraloc.toml`), writing
/// `report.json` and `pose.json` there; with `truth`, the report also scores every stage against
/// the scene's `truth.json`.
pub fn localize_scene(bin: &str, dir: &Path, truth: bool) -> std::process::Output {
    let mut cmd = std::process::Command::new(bin);
    cmd.arg("localize")
        .arg("--config")
        .arg(dir.join("infraloc.toml"))
        .arg("--report")
        .arg(dir.join("report.json"))
        .arg("--out")
        .arg(dir.join("pose.json"));
    if truth {
        cmd.arg("--truth").arg(dir.join("truth.json"));
    }
    cmd.output().expect("run infraloc localize")
}

/// Whether the tests run under CI (`CI` set to anything but empty, `0` or `false`), where every
/// tool and data set a test needs must be present.
pub fn under_ci() -> bool {
    std::env::var("CI").is_ok_and(|v| !matches!(v.as_str(), "" | "0" | "false"))
}

/// Say that `test` is skipped and why, straight to the process's stderr: libtest captures
/// `eprintln!` of a passing test, which would make the skip silent.
pub fn skip(test: &str, why: &str) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr(), "\nSKIPPED {test}: {why}");
}

/// A test that needs something this machine lacks: fails under CI (where it must be there),
/// otherwise skips visibly ([`skip`]).
pub fn skip_unless_ci(test: &str, why: &str) {
    assert!(!under_ci(), "{test}: {why} (required under CI)");
    skip(test, why);
}

/// Check OpenMetrics/Prometheus text with Prometheus's own parser and linter (`promtool check
/// metrics`, Debian package `prometheus`, installed by `.ci/setup`). `Err` with promtool's
/// complaint if it refuses the text. Without promtool the test fails under CI and otherwise
/// says on stderr that the parser check was skipped ([`skip_unless_ci`], `Ok(false)`).
pub fn promtool_check(text: &str) -> Result<bool, String> {
    use std::io::Write;
    use std::process::{Command, Stdio};
    let child = Command::new("promtool")
        .args(["check", "metrics"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn();
    let mut child = match child {
        Ok(c) => c,
        Err(e) => {
            skip_unless_ci(
                "the Prometheus parser check (promtool check metrics)",
                &format!("promtool not found ({e}); `bash .ci/setup` unpacks it"),
            );
            return Ok(false);
        }
    };
    child
        .stdin
        .take()
        .unwrap()
        .write_all(text.as_bytes())
        .unwrap();
    let out = child.wait_with_output().unwrap();
    if out.status.success() {
        Ok(true)
    } else {
        Err(format!(
            "promtool check metrics refused the text ({}): {}{}",
            out.status,
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        ))
    }
}

/// Run the crate's `infraloc` binary with `args`; its output (a failure to start panics).
pub fn infraloc(args: &[&str]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_infraloc"))
        .args(args)
        .output()
        .expect("run infraloc")
}

/// A path as an argument (the tests' paths are UTF-8).
pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Wait until `child` (spawned with a piped stdout) prints a line containing `ready`: the crash
/// tests time their kills from there, not from the spawn, so a child slow to start under load is
/// still killed while it writes.
pub fn wait_until_ready(child: &mut std::process::Child) {
    use std::io::BufRead;
    let mut out = std::io::BufReader::new(child.stdout.take().expect("a piped stdout"));
    let mut line = String::new();
    while out.read_line(&mut line).unwrap() > 0 && !line.contains("ready") {
        line.clear();
    }
}
