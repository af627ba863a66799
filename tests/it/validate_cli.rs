//! `infraloc validate` opens what the config names (issue 19, deliverable 1): each bad input of
//! a technician's is one line naming its key, exit 78; several at once are all reported; what
//! may appear later (a device, the state directory) is a warning; the service refuses the same
//! config at start and creates its own state directory.

use crate::common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_infraloc");

/// `infraloc simulate --seed 3 --preset small`, shared with the other modules (read only: the
/// configs and outputs are in work directories).
fn scene() -> &'static Path {
    common::shared_scene(BIN, &["--seed", "3", "--preset", "small"])
}

/// A work dir with the scene's config made absolute (pose, socket in the work dir), `edit`
/// applied. Returns the dir and the config path.
fn config(edit: impl FnOnce(&mut toml::Table, &Path)) -> (tempfile::TempDir, PathBuf) {
    let s = scene();
    let w = tempfile::tempdir().unwrap();
    let mut t: toml::Table =
        toml::from_str(&std::fs::read_to_string(s.join("infraloc.toml")).unwrap()).unwrap();
    let abs = |p: &str| s.join(p).display().to_string();
    set(&mut t, "camera", "intrinsics-file", abs("camera.yaml"));
    set(&mut t, "camera", "frames", abs("frames"));
    set(&mut t, "gps", "path", abs("gps.nmea"));
    set(&mut t, "map", "tiles", abs("tiles"));
    set(&mut t, "output", "pose", "pose.json");
    set(&mut t, "daemon", "socket", "run/control.sock");
    edit(&mut t, w.path());
    let cfg = w.path().join("infraloc.toml");
    std::fs::write(&cfg, toml::to_string(&t).unwrap()).unwrap();
    (w, cfg)
}

fn set(t: &mut toml::Table, sec: &str, k: &str, v: impl Into<toml::Value>) {
    t.entry(sec)
        .or_insert_with(|| toml::Value::Table(Default::default()))
        .as_table_mut()
        .unwrap()
        .insert(k.into(), v.into());
}

fn validate(cfg: &Path, extra: &[&str]) -> Output {
    Command::new(BIN)
        .arg("validate")
        .arg("--config")
        .arg(cfg)
        .args(extra)
        .output()
        .unwrap()
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

type Edit = Box<dyn Fn(&mut toml::Table, &Path)>;

/// The bad inputs, each with the words its one line must contain.
fn bad_inputs() -> Vec<(&'static str, Edit, Vec<&'static str>)> {
    let path = |sec: &'static str, key: &'static str, rel: &'static str| -> Edit {
        Box::new(move |t, w| set(t, sec, key, w.join(rel).display().to_string()))
    };
    vec![
        (
            "intrinsics file missing",
            path("camera", "intrinsics-file", "nope.yaml"),
            vec!["[camera] intrinsics-file", "nope.yaml", "No such file"],
        ),
        (
            "intrinsics file is a directory",
            Box::new(|t, w| {
                std::fs::create_dir_all(w.join("cam.d")).unwrap();
                set(
                    t,
                    "camera",
                    "intrinsics-file",
                    w.join("cam.d").display().to_string(),
                );
            }),
            vec!["[camera] intrinsics-file", "is a directory"],
        ),
        (
            "intrinsics file does not parse",
            Box::new(|t, w| {
                std::fs::write(w.join("cam.yaml"), "%YAML:1.0\nfoo: [1, 2\n").unwrap();
                set(
                    t,
                    "camera",
                    "intrinsics-file",
                    w.join("cam.yaml").display().to_string(),
                );
            }),
            vec!["[camera] intrinsics-file", "cam.yaml"],
        ),
        (
            "tile cache is a file",
            Box::new(|t, w| {
                std::fs::write(w.join("tiles"), "x").unwrap();
                set(t, "map", "tiles", w.join("tiles").display().to_string());
            }),
            vec!["[map] tiles", "is not a directory"],
        ),
        (
            "tile cache has no readable manifest",
            Box::new(|t, w| {
                std::fs::create_dir_all(w.join("tiles/t1")).unwrap();
                set(t, "map", "tiles", w.join("tiles").display().to_string());
            }),
            vec!["[map] tiles", "no tile with a readable manifest"],
        ),
        (
            "frames directory missing",
            path("camera", "frames", "no-frames"),
            vec!["[camera] frames", "no-frames"],
        ),
        (
            "pose path is a directory",
            Box::new(|t, w| {
                std::fs::create_dir_all(w.join("pose.d")).unwrap();
                set(t, "output", "pose", w.join("pose.d").display().to_string());
            }),
            vec!["[output] pose", "is a directory"],
        ),
        (
            "pose path empty",
            Box::new(|t, _| set(t, "output", "pose", "")),
            vec!["[output] pose is empty"],
        ),
        (
            "socket empty",
            Box::new(|t, _| set(t, "daemon", "socket", "")),
            vec!["[daemon] socket is empty"],
        ),
        (
            "socket path is a regular file",
            Box::new(|t, w| {
                std::fs::write(w.join("sock"), "").unwrap();
                set(t, "daemon", "socket", w.join("sock").display().to_string());
            }),
            vec!["[daemon] socket", "is not a socket"],
        ),
        (
            "retry attempts huge",
            Box::new(|t, _| set(t, "camera", "retry-attempts", 4_294_967_295_i64)),
            vec!["[camera] retry-attempts = 4294967295", "use 1 to 20"],
        ),
        (
            "retry backoff huge",
            Box::new(|t, _| set(t, "camera", "retry-backoff-ms", 4_294_967_295_i64)),
            vec!["[camera] retry-backoff-ms = 4294967295", "30000"],
        ),
        (
            "retry-max-s infinite",
            Box::new(|t, _| set(t, "daemon", "retry-max-s", f64::INFINITY)),
            vec!["[daemon] retry-max-s = inf is not a finite number"],
        ),
        (
            "report directory missing",
            path("output", "report", "missing/dir/r.json"),
            vec!["[output] report", "missing/dir"],
        ),
        (
            "NMEA log missing",
            path("gps", "path", "none.nmea"),
            vec!["[gps] path", "none.nmea"],
        ),
        (
            "match file unreadable",
            Box::new(|t, w| {
                std::fs::write(w.join("m.csv"), "a,b\n1,2\n").unwrap();
                set(t, "init", "matcher", "match-file");
                set(
                    t,
                    "init",
                    "matcher-path",
                    w.join("m.csv").display().to_string(),
                );
            }),
            vec!["[init] matcher-path", "m.csv"],
        ),
    ]
}

#[test]
fn the_good_scene_config_validates() {
    let (_w, cfg) = config(|_, _| {});
    let out = validate(&cfg, &[]);
    assert_eq!(out.status.code(), Some(0), "{}", text(&out.stderr));
    assert_eq!(text(&out.stdout).trim(), "config OK");
}

#[test]
fn each_bad_input_is_one_line_naming_its_key_exit_78() {
    for (name, edit, want) in bad_inputs() {
        let (_w, cfg) = config(|t, w| edit(t, w));
        let out = validate(&cfg, &[]);
        let err = text(&out.stderr);
        assert_eq!(out.status.code(), Some(78), "{name}: {err}");
        let lines: Vec<&str> = err.lines().filter(|l| !l.starts_with("warning:")).collect();
        assert_eq!(lines.len(), 1, "{name}: {err}");
        for w in &want {
            assert!(lines[0].contains(w), "{name}: {w:?} not in {err}");
        }
        assert!(lines[0].starts_with("infraloc: config "), "{name}: {err}");
        assert!(!out.status.success() && text(&out.stdout).is_empty());
    }
}

#[test]
fn every_problem_is_reported_at_once_in_text_and_json() {
    let cases = bad_inputs();
    // One edit per key (the first of each key), all applied to one config.
    let mut seen = Vec::new();
    let picked: Vec<_> = cases
        .iter()
        .filter(|(_, _, want)| {
            let key = want[0]
                .split(" =")
                .next()
                .unwrap()
                .split(" is")
                .next()
                .unwrap();
            let new = !seen.contains(&key.to_string());
            seen.push(key.to_string());
            new
        })
        .collect();
    let (_w, cfg) = config(|t, w| {
        for (_, edit, _) in &picked {
            edit(t, w);
        }
    });
    let out = validate(&cfg, &[]);
    assert_eq!(out.status.code(), Some(78));
    let err = text(&out.stderr);
    let lines: Vec<&str> = err.lines().filter(|l| !l.starts_with("warning:")).collect();
    assert_eq!(lines.len(), picked.len(), "{err}");
    for (name, _, want) in &picked {
        assert!(
            lines.iter().any(|l| l.contains(want[0])),
            "{name}: {} missing from {err}",
            want[0]
        );
    }
    let out = validate(&cfg, &["--json"]);
    assert_eq!(out.status.code(), Some(78));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["ok"], false);
    assert_eq!(v["problems"].as_array().unwrap().len(), picked.len(), "{v}");
}

#[test]
fn what_may_appear_later_is_a_warning() {
    let (w, cfg) = config(|t, w| {
        set(t, "camera", "source", "v4l2");
        set(t, "camera", "device", "/dev/video-not-plugged-in");
        t["camera"].as_table_mut().unwrap().remove("frames");
        set(
            t,
            "output",
            "pose",
            w.join("state/pose.json").display().to_string(),
        );
    });
    let out = validate(&cfg, &[]);
    let err = text(&out.stderr);
    if cfg!(feature = "v4l") {
        assert_eq!(out.status.code(), Some(0), "{err}");
        assert!(
            err.contains("warning:") && err.contains("[camera] device /dev/video-not-plugged-in"),
            "{err}"
        );
    } else {
        // Without the v4l2 backend the source itself is the problem, named as such.
        assert!(
            err.contains("this build has no V4L2 capture") && err.contains("--features v4l"),
            "{err}"
        );
        assert_eq!(out.status.code(), Some(78), "{err}");
    }
    assert!(
        err.contains("[output] pose: directory") && err.contains("the service creates it"),
        "{err}"
    );
    assert!(
        !w.path().join("state").exists(),
        "validate must not create it"
    );
}

#[test]
fn keys_only_skips_the_machine_checks() {
    let (_w, cfg) = config(|t, w| set(t, "camera", "frames", w.join("gone").display().to_string()));
    let out = validate(&cfg, &["--keys-only"]);
    assert_eq!(out.status.code(), Some(0), "{}", text(&out.stderr));
    let out = validate(&cfg, &[]);
    assert_eq!(out.status.code(), Some(78));
}

#[test]
fn read_only_output_directory_is_a_problem() {
    use std::os::unix::fs::PermissionsExt;
    if unsafe_euid_is_root() {
        common::skip(
            "validate_cli::keys_only_skips_the_machine_checks",
            "running as root, which may write any directory",
        );
        return;
    }
    let (w, cfg) = config(|t, w| {
        let ro = w.join("ro");
        std::fs::create_dir(&ro).unwrap();
        set(
            t,
            "output",
            "report",
            ro.join("r.json").display().to_string(),
        );
    });
    std::fs::set_permissions(w.path().join("ro"), std::fs::Permissions::from_mode(0o555)).unwrap();
    let out = validate(&cfg, &[]);
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(78), "{err}");
    assert!(
        err.contains("[output] report") && err.contains("not writable"),
        "{err}"
    );
}

fn unsafe_euid_is_root() -> bool {
    // /proc/self/status: "Uid: real effective saved fs".
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("Uid:"))
                .and_then(|l| l.split_whitespace().nth(2).map(|u| u == "0"))
        })
        .unwrap_or(false)
}

#[test]
fn the_service_refuses_the_same_problems_at_start() {
    let (w, cfg) = config(|t, w| {
        set(
            t,
            "camera",
            "frames",
            w.join("no-frames").display().to_string(),
        );
        set(t, "daemon", "retry-max-s", f64::INFINITY);
    });
    let out = Command::new(BIN)
        .arg("daemon")
        .arg("--config")
        .arg(&cfg)
        .output()
        .unwrap();
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(78), "{err}");
    assert!(
        err.contains("[camera] frames") && err.contains("[daemon] retry-max-s"),
        "{err}"
    );
    assert!(!w.path().join("run/control.sock").exists());
}

#[test]
fn the_service_creates_its_state_directory() {
    let (w, cfg) = config(|t, w| {
        set(
            t,
            "output",
            "pose",
            w.join("state/sub/pose.json").display().to_string(),
        );
        set(t, "daemon", "retry-initial-s", 600.0);
    });
    let mut child = Command::new(BIN)
        .arg("daemon")
        .arg("--config")
        .arg(&cfg)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let state = w.path().join("state/sub");
    let start = Instant::now();
    while !(state.is_dir() && w.path().join("run/control.sock").exists()) {
        if let Ok(Some(st)) = child.try_wait() {
            panic!("daemon exited ({st}) before creating {}", state.display());
        }
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "no state directory"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    use std::os::unix::fs::PermissionsExt;
    let mode = std::fs::metadata(&state).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode, 0o750);
    // SIGTERM: a clean stop, the log says what it did.
    let pid = child.id().to_string();
    Command::new("kill").args(["-TERM", &pid]).status().unwrap();
    let out = child.wait_with_output().unwrap();
    let log = text(&out.stderr);
    assert!(out.status.success(), "{log}");
    assert!(log.contains("created the state directory"), "{log}");
}

/// `localize`'s outputs are checked before any work and written all-or-nothing (deliverable 2):
/// a report or overlay that cannot be written fails at once naming the user's path (never a
/// temp file), the pose file untouched; temp files a killed run left are removed.
#[test]
fn localize_checks_its_outputs_before_the_work() {
    let (w, cfg) = config(|_, _| {});
    let pose = w.path().join("pose.json");
    std::fs::write(&pose, "OLD").unwrap();
    let stale = w.path().join(".pose.json.tmp.2147483646.3");
    std::fs::write(&stale, "half a pose").unwrap();
    std::fs::create_dir(w.path().join("ov.png")).unwrap();
    let run = |extra: &[&str]| {
        Command::new(BIN)
            .args(["localize", "--config"])
            .arg(&cfg)
            .arg("--out")
            .arg(&pose)
            .args(extra)
            .output()
            .unwrap()
    };
    let missing = w.path().join("missing/dir/r.json");
    let overlay = w.path().join("ov.png");
    let out = run(&[
        "--report",
        missing.to_str().unwrap(),
        "--overlay",
        overlay.to_str().unwrap(),
    ]);
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(
        err.contains(&format!("--report {}", missing.display())) && err.contains("No such file"),
        "{err}"
    );
    assert!(
        err.contains(&format!("--overlay {} is a directory", overlay.display())),
        "{err}"
    );
    assert!(!err.contains(".tmp."), "names a temp file: {err}");
    assert_eq!(std::fs::read_to_string(&pose).unwrap(), "OLD");
    assert!(!stale.exists(), "the killed run's temp file is still there");
    // The same report path from the config is a config problem: exit 78, naming the key.
    let (_w2, cfg2) = config(|t, w| {
        set(
            t,
            "output",
            "report",
            w.join("missing/r.json").display().to_string(),
        )
    });
    let out = Command::new(BIN)
        .args(["localize", "--config"])
        .arg(&cfg2)
        .output()
        .unwrap();
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(78), "{err}");
    assert!(err.contains("[output] report"), "{err}");
}
