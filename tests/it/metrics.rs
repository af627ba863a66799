//! The service's metrics file (docs/fleet.md): its text passes Prometheus's own parser, and its
//! writes are atomic: writers killed with SIGKILL in a loop never leave a partial `infraloc.prom`
//! for a reader to see. The file read from a running service is in tests/it/daemon_e2e.rs.

use crate::common;

use infraloc::daemon::metrics;
use infraloc::daemon::status::{
    DriftCheck, DriftOutcome, DriftSearch, DriftVerdict, JobKind, Optimum, RunOutcome, RunResult,
    Running, Served, StageTime,
};
use infraloc::daemon::{State, Status};
use infraloc::localize::refine::quality::Sigma;
use infraloc::map::cache::SkippedTile;
use infraloc::stage::StageName;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// A status with every optional part present (tilt σ included), or a failed one.
fn status(full: bool, uptime_s: f64) -> Status {
    let sigma = Sigma {
        x: 0.011,
        y: 0.023,
        z: 0.004,
        yaw: 0.031,
        pitch: Some(0.2),
        roll: Some(f64::INFINITY),
    };
    let localized = RunResult {
        finished_utc: "2026-11-22T16:27:01.561Z".into(),
        seconds: 19.5,
        outcome: RunOutcome::Localized {
            served: true,
            decision: "first pose".into(),
            camera_center: [275_013.069, 4_684_273.495, 267.557],
            yaw_pitch_roll_deg: [135.765, -88.0, 0.1],
            score: Some(0.123),
            sigma: Some(sigma),
            stages: ["capture", "prior", "tile", "pnp", "mi"]
                .iter()
                .enumerate()
                .map(|(i, n)| StageTime {
                    name: n.to_string(),
                    seconds: 0.5 + i as f64,
                })
                .collect(),
            skipped_tiles: vec![SkippedTile {
                dir: "/c/aaa \"odd\"\\name".into(),
                reason: "tile: /c/aaa/tile.toml: truncated\nsecond line".into(),
            }],
        },
        pooled_frames: vec!["2026-11-22T13:01:00Z".into(), "2026-11-22T12:00:00Z".into()],
    };
    let failed = RunResult {
        finished_utc: "2026-11-22T17:00:00Z".into(),
        seconds: 3.0,
        outcome: RunOutcome::Failed {
            error: "prior: no fix".into(),
            retry_in_s: 60.0,
        },
        pooled_frames: Vec::new(),
    };
    Status {
        state: if full { State::Ok } else { State::Failed },
        summary: "summary".into(),
        pid: 42,
        version: env!("CARGO_PKG_VERSION").into(),
        config: "/etc/infraloc/infraloc.toml".into(),
        uptime_s,
        served: full.then(|| Served {
            file: "/var/lib/infraloc/pose.json".into(),
            timestamp_utc: "2026-11-22T16:27:01Z".into(),
            tile_id: "sim-0001".into(),
            crs: "EPSG:32617".into(),
            camera_center: [275_013.069, 4_684_273.495, 267.557],
            yaw_pitch_roll_deg: [135.765, -88.0, 0.1],
            score: Some(0.123),
            sigma: Some(sigma),
            grade: "precise".into(),
            grade_reason: None,
        }),
        running: full.then_some(Running {
            job: JobKind::DriftCheck,
            why: None,
            stage: StageName::Capture,
            seconds: 1.0,
        }),
        last_result: Some(if full { localized } else { failed }),
        last_drift_check: full.then(|| DriftCheck {
            checked_utc: "2026-11-22T16:57:20.885Z".into(),
            outcome: DriftOutcome::Ran(DriftSearch {
                verdict: DriftVerdict {
                    moved: false,
                    reason: None,
                    shift_m: 0.004,
                    dz_m: -0.002,
                    yaw_deg: -0.1,
                },
                optimum: Optimum {
                    camera_center: [0.0; 3],
                    yaw_pitch_roll_deg: [0.0; 3],
                    nmi: 0.12,
                },
            }),
            resolved: None,
        }),
        failures_in_a_row: if full { 0 } else { 2 },
        next_localize_in_s: None,
        next_drift_check_in_s: None,
        reload_error: None,
        stored_frames: if full {
            [
                "2026-11-22T12:00:00Z",
                "2026-11-22T13:01:00Z",
                "2026-11-22T16:27:01Z",
            ]
            .map(|t| infraloc::frames::FrameEntry {
                file: format!("frame-{t}.png"),
                taken_utc: t.into(),
                bytes: 2_000_000,
            })
            .to_vec()
        } else {
            Vec::new()
        },
    }
}

/// The value of the one sample line starting with `series ` (name and labels as written).
fn value(text: &str, series: &str) -> Option<String> {
    text.lines().find_map(|l| {
        l.strip_prefix(series)?
            .strip_prefix(' ')
            .map(str::to_string)
    })
}

#[test]
fn the_metrics_pass_prometheus_own_parser() {
    let now = infraloc::posefile::parse_utc("2026-11-22T17:27:01Z").unwrap();
    let full = metrics::render(&status(true, 1860.0), now);
    let failed = metrics::render(&status(false, 5.0), now);
    for text in [&full, &failed] {
        assert!(text.ends_with("\n# EOF\n"), "{text}");
        if let Err(e) = common::promtool_check(text) {
            panic!("{e}\n{text}");
        }
    }
    // The checker can fail: a sample without a number is refused.
    if common::promtool_check("# TYPE x gauge\nx{a=\"1\"} one\n").unwrap_or(false) {
        panic!("promtool accepted a sample without a number");
    }

    // What an operator alerts on, with the values of the status.
    for (series, want) in [
        ("infraloc_state{state=\"ok\"}", "1"),
        ("infraloc_state{state=\"degraded\"}", "0"),
        ("infraloc_pose_served", "1"),
        ("infraloc_pose_age_seconds", "3600"),
        ("infraloc_pose_sigma_meters{axis=\"y\"}", "0.023"),
        ("infraloc_pose_sigma_degrees{axis=\"yaw\"}", "0.031"),
        ("infraloc_pose_sigma_degrees{axis=\"pitch\"}", "0.2"),
        ("infraloc_pose_sigma_degrees{axis=\"roll\"}", "+Inf"),
        ("infraloc_last_run_sigma_meters{axis=\"x\"}", "0.011"),
        (
            "infraloc_last_run_stage_duration_seconds{stage=\"mi\"}",
            "4.5",
        ),
        ("infraloc_last_run_duration_seconds", "19.5"),
        ("infraloc_last_run_skipped_tiles", "1"),
        ("infraloc_consecutive_failures", "0"),
        ("infraloc_stored_frames", "3"),
        ("infraloc_last_run_pooled_frames", "2"),
        ("infraloc_job_running{job=\"drift-check\"}", "1"),
        ("infraloc_drift_offset_meters{axis=\"horizontal\"}", "0.004"),
        ("infraloc_drift_offset_meters{axis=\"z\"}", "-0.002"),
        ("infraloc_drift_offset_degrees{axis=\"yaw\"}", "-0.1"),
        ("infraloc_drift_moved", "0"),
        ("infraloc_uptime_seconds", "1860"),
    ] {
        assert_eq!(value(&full, series).as_deref(), Some(want), "{series}");
    }
    let build = format!(
        "infraloc_build_info{{version=\"{}\",arch=\"{}\",os=\"linux\"}}",
        env!("CARGO_PKG_VERSION"),
        std::env::consts::ARCH
    );
    assert_eq!(value(&full, &build).as_deref(), Some("1"), "{full}");
    // No pose, a failed run: the pose and result series are absent, not NaN.
    assert_eq!(
        value(&failed, "infraloc_state{state=\"failed\"}").as_deref(),
        Some("1")
    );
    assert_eq!(
        value(&failed, "infraloc_consecutive_failures").as_deref(),
        Some("2")
    );
    assert_eq!(
        value(&failed, "infraloc_last_run_success").as_deref(),
        Some("0")
    );
    assert!(!failed.contains("infraloc_pose_age_seconds"), "{failed}");
    assert!(!failed.contains("sigma"), "{failed}");
    assert!(!failed.contains("NaN"), "{failed}");
}

/// The rendered text, byte for byte, of a populated status and of a failed one (build version and
/// architecture written as `{VERSION}` and `{ARCH}` in the pinned files).
#[test]
fn the_rendered_text_is_pinned() {
    let now = infraloc::posefile::parse_utc("2026-11-22T17:27:01Z").unwrap();
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/metrics");
    for (full, uptime_s, file) in [(true, 1860.0, "full.prom"), (false, 5.0, "failed.prom")] {
        let got = metrics::render(&status(full, uptime_s), now);
        let want = std::fs::read_to_string(dir.join(file))
            .unwrap()
            .replace("{VERSION}", env!("CARGO_PKG_VERSION"))
            .replace("{ARCH}", std::env::consts::ARCH);
        assert_eq!(got, want, "{file}");
    }
}

/// Child process of [`a_killed_writer_never_leaves_a_partial_file`] (run by it with `--ignored`):
/// write the metrics file over and over until killed.
#[test]
#[ignore = "the child process of a_killed_writer_never_leaves_a_partial_file"]
fn metrics_writer_child() {
    let Some(dir) = std::env::var_os("INFRALOC_METRICS_WRITER_DIR") else {
        return;
    };
    // Tell the parent the writing loop is starting: the kill moments count from here, so a child
    // slow to start under load is not killed before it writes.
    println!("ready");
    let mut n = 0u64;
    loop {
        // Each write differs (the uptime), and a long stage list makes each write several KB.
        let mut s = status(true, n as f64);
        if let Some(RunResult {
            outcome: RunOutcome::Localized { stages, .. },
            ..
        }) = s.last_result.as_mut()
        {
            for i in 0..200 {
                stages.push(StageTime {
                    name: format!("stage-{i}"),
                    seconds: i as f64,
                });
            }
        }
        metrics::write(Path::new(&dir), &s).unwrap();
        n += 1;
    }
}

#[test]
fn a_killed_writer_never_leaves_a_partial_file() {
    let d = tempfile::tempdir().unwrap();
    let file = metrics::file_in(d.path());
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let reader = {
        let (file, stop) = (file.clone(), stop.clone());
        std::thread::spawn(move || {
            let (mut reads, mut contents) = (0u64, std::collections::HashSet::new());
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                if let Ok(text) = std::fs::read_to_string(&file) {
                    reads += 1;
                    assert!(
                        text.starts_with("# HELP infraloc_build_info") && text.ends_with("# EOF\n"),
                        "partial metrics file ({} bytes): …{}",
                        text.len(),
                        &text[text.len().saturating_sub(80)..]
                    );
                    contents.insert(value(&text, "infraloc_uptime_seconds"));
                }
            }
            (reads, contents.len())
        })
    };
    let exe = std::env::current_exe().unwrap();
    let mut rng_state = 0x2545_f491_4f6c_dd1du64;
    let kills = 30;
    let start = Instant::now();
    for _ in 0..kills {
        let mut child = Command::new(&exe)
            .args([
                "--exact",
                // The child is a test of this binary, named by its module path.
                "metrics::metrics_writer_child",
                "--ignored",
                "--test-threads=1",
                "--nocapture",
            ])
            .env("INFRALOC_METRICS_WRITER_DIR", d.path())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        common::wait_until_ready(&mut child);
        // xorshift: a seeded spread of kill moments, 20-120 ms into the writer's life.
        rng_state ^= rng_state << 13;
        rng_state ^= rng_state >> 7;
        rng_state ^= rng_state << 17;
        std::thread::sleep(Duration::from_millis(20 + rng_state % 100));
        child.kill().unwrap(); // SIGKILL
        child.wait().unwrap();
    }
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let (reads, distinct) = reader.join().unwrap();
    eprintln!(
        "{kills} writers killed in {:.1} s; {reads} complete reads, {distinct} distinct files seen",
        start.elapsed().as_secs_f64()
    );
    assert!(reads > 0 && distinct > 1, "{reads} reads, {distinct} files");
    // The only `.prom` file is the complete one; killed writes left at most temp files, which
    // node_exporter ignores (not `*.prom`) and the next start removes.
    let names: Vec<String> = std::fs::read_dir(d.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    let proms: Vec<&String> = names.iter().filter(|n| n.ends_with(".prom")).collect();
    assert_eq!(proms, [metrics::FILE_NAME], "{names:?}");
    infraloc::persist::remove_stale_temps(&file);
    let left: Vec<String> = std::fs::read_dir(d.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(
        left,
        [metrics::FILE_NAME],
        "temp files not cleaned: {left:?}"
    );
    let text = std::fs::read_to_string(&file).unwrap();
    if let Err(e) = common::promtool_check(&text) {
        panic!("{e}");
    }
}
