//! A served pose for the georeferencing checks: the real `infraloc daemon` on a simulated scene,
//! the scene's truth stored as the served pose, the camera an absent device (so the stored pose
//! stays served). Shared by `tests/it/georef_service.rs` and `benches/georef_socket.rs`.
#![allow(dead_code)]

use infraloc::posefile::{read_pose, PoseFile, PoseQuality};
use serde_json::{json, Value};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

/// The binary under test.
pub(crate) const BIN: &str = env!("CARGO_BIN_EXE_infraloc");
/// `timestamp_utc` of the stored truth pose.
pub(crate) const STORED_AT: &str = "2026-11-01T00:00:00Z";

pub(crate) fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// The `simulate` arguments of the served scene.
pub(crate) const SCENE: [&str; 6] = ["--seed", "3", "--preset", "small", "--difficulty", "hard"];

pub(crate) fn simulate(dir: &Path) {
    let out = Command::new(BIN)
        .arg("simulate")
        .args(SCENE)
        .arg("--out")
        .arg(dir)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", text(&out.stderr));
}

pub(crate) fn set(t: &mut toml::Table, sec: &str, k: &str, v: impl Into<toml::Value>) {
    t.entry(sec.to_string())
        .or_insert_with(|| toml::Value::Table(Default::default()))
        .as_table_mut()
        .unwrap()
        .insert(k.into(), v.into());
}

/// The scene's config with absolute scene paths, the pose and socket in `work`; with
/// `camera_ok` false the camera is an absent v4l2 device (localization fails at once).
pub(crate) fn write_config(scene: &Path, work: &Path, camera_ok: bool) -> PathBuf {
    let mut t: toml::Table =
        toml::from_str(&std::fs::read_to_string(scene.join("infraloc.toml")).unwrap()).unwrap();
    let abs = |p: &str| scene.join(p).display().to_string();
    set(&mut t, "camera", "intrinsics-file", abs("camera.yaml"));
    set(&mut t, "camera", "frames", abs("frames"));
    if !camera_ok {
        set(&mut t, "camera", "source", "v4l2");
        set(&mut t, "camera", "device", "/dev/video-absent");
        set(&mut t, "camera", "retry-attempts", 1);
    }
    set(&mut t, "gps", "path", abs("gps.nmea"));
    set(&mut t, "map", "tiles", abs("tiles"));
    set(&mut t, "output", "pose", "pose.json");
    set(&mut t, "daemon", "socket", "run/control.sock");
    set(&mut t, "daemon", "retry-initial-s", 600.0);
    set(&mut t, "daemon", "drift-check-interval-min", 0.0);
    let cfg = work.join("infraloc.toml");
    std::fs::write(&cfg, toml::to_string(&t).unwrap()).unwrap();
    cfg
}

/// The truth as a served pose file, with a 4-axis covariance (σ 1 cm, 1 cm, 1 cm, 0.05°).
pub(crate) fn store_truth(scene: &Path, work: &Path) {
    let t = read_pose(&scene.join("truth.json")).unwrap();
    let tile = std::fs::read_dir(scene.join("tiles"))
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .file_name();
    let mut f = PoseFile::new(
        &t.pose,
        t.crs.unwrap(),
        &tile.to_string_lossy(),
        STORED_AT.into(),
    );
    f.quality = PoseQuality::from_value(json!({
        "score": 1.0,
        "sigma": {"x": 0.01, "y": 0.01, "z": 0.01, "yaw": 0.05},
        "covariance": {
            "axes": ["x", "y", "z", "yaw"],
            "units": ["m", "m", "m", "deg"],
            "matrix": [[1e-4, 0.0, 0.0, 0.0], [0.0, 1e-4, 0.0, 0.0],
                       [0.0, 0.0, 1e-4, 0.0], [0.0, 0.0, 0.0, 0.0025]],
        },
    }));
    std::fs::write(work.join("pose.json"), f.to_json()).unwrap();
}

pub(crate) struct Daemon {
    pub(crate) child: Child,
    pub(crate) log: PathBuf,
}

impl Daemon {
    pub(crate) fn start(cfg: &Path) -> Daemon {
        let log = cfg.with_file_name("daemon.log");
        let child = Command::new(BIN)
            .arg("daemon")
            .arg("--config")
            .arg(cfg)
            .env_remove("NOTIFY_SOCKET")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&log).unwrap())
            .spawn()
            .unwrap();
        Daemon { child, log }
    }

    pub(crate) fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    /// Poll `status --json` until `cond` holds (two minutes at most).
    pub(crate) fn wait_status(&mut self, cfg: &Path, cond: impl Fn(&Value) -> bool) -> Value {
        let start = Instant::now();
        loop {
            if let Ok(Some(st)) = self.child.try_wait() {
                panic!("daemon exited ({st}): {}", self.log());
            }
            let out = cli(cfg, &["status", "--json"], "");
            if let Ok(v) = serde_json::from_slice::<Value>(&out.stdout) {
                if cond(&v) {
                    return v;
                }
            }
            assert!(
                start.elapsed() < Duration::from_secs(120),
                "status never got there: {}; {}",
                text(&out.stdout),
                self.log()
            );
            std::thread::sleep(Duration::from_millis(100));
        }
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// `infraloc ARGS --config CFG` with `stdin`.
pub(crate) fn cli(cfg: &Path, args: &[&str], stdin: &str) -> Output {
    let mut c = Command::new(BIN)
        .args(args)
        .arg("--config")
        .arg(cfg)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    c.stdin.take().unwrap().write_all(stdin.as_bytes()).unwrap();
    c.wait_with_output().unwrap()
}

/// A raw request over the socket, as a pipeline without infraloc's client would send it.
pub(crate) fn raw(socket: &Path, req: &Value) -> Value {
    use infraloc::control::{read_frame, write_frame};
    let mut s = std::os::unix::net::UnixStream::connect(socket).unwrap();
    write_frame(&mut s, req.to_string().as_bytes()).unwrap();
    serde_json::from_slice(&read_frame(&mut s, 64 << 20).unwrap().unwrap()).unwrap()
}

/// 1,000 pixels, a 40 × 25 grid of cell centres over a `w` × `h` image: the batch whose
/// request latency docs/benchmarks.md reports.
pub(crate) fn grid_1000(w: f64, h: f64) -> Vec<[Option<f64>; 2]> {
    (0..1000)
        .map(|k| {
            let (i, j) = ((k % 40) as f64, (k / 40) as f64);
            [Some((i + 0.5) * w / 40.0), Some((j + 0.5) * h / 25.0)]
        })
        .collect()
}
