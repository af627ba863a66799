//! The service's status as OpenMetrics text, for Prometheus through node_exporter's textfile
//! collector (`[daemon] metrics-dir`) and for `infraloc status --format openmetrics`. One
//! rendering, [`render`], serves both, so what a scrape sees is what a technician sees.
//!
//! Only gauges are used, so the text is valid both as OpenMetrics and as the Prometheus text
//! format node_exporter parses (it reads the closing `# EOF` as a comment). Values that do not
//! exist (no pose served, no run yet, a pose without σ) are left out rather than written as
//! `NaN`, so an alert on them can use `absent()`.

use super::status::{DriftOutcome, RunOutcome, State, Status};
use crate::localize::refine::quality::Sigma;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// The file the service writes in `[daemon] metrics-dir`. node_exporter reads `*.prom`; the
/// temp file of an atomic write (`.infraloc.prom.tmp.PID.N`) does not match, so a scrape never
/// sees a partial file.
pub const FILE_NAME: &str = "infraloc.prom";

/// The metrics file in directory `dir`.
pub fn file_in(dir: &Path) -> PathBuf {
    dir.join(FILE_NAME)
}

/// Seconds since the Unix epoch of an RFC 3339 timestamp as the service writes them.
fn unix_seconds(utc: &str) -> Option<f64> {
    crate::posefile::parse_utc(utc)
}

/// One metric family being written.
struct Family<'a> {
    out: &'a mut String,
}

impl Family<'_> {
    /// A sample with labels (`(name, value)` pairs).
    fn sample(&mut self, name: &str, labels: &[(&str, &str)], v: f64) {
        self.out.push_str(name);
        if !labels.is_empty() {
            self.out.push('{');
            for (i, (k, val)) in labels.iter().enumerate() {
                if i > 0 {
                    self.out.push(',');
                }
                let _ = write!(self.out, "{k}=\"{}\"", escape(val));
            }
            self.out.push('}');
        }
        let _ = writeln!(self.out, " {}", number(v));
    }
}

/// Write a gauge family's metadata, then its samples through `f`.
fn gauge(out: &mut String, name: &str, help: &str, f: impl FnOnce(&mut Family<'_>)) {
    let _ = writeln!(out, "# HELP {name} {help}");
    let _ = writeln!(out, "# TYPE {name} gauge");
    f(&mut Family { out });
}

/// A label value with `\`, `"` and newlines escaped.
fn escape(s: &str) -> String {
    s.replace('\\', "\\\\")
        .replace('"', "\\\"")
        .replace('\n', "\\n")
}

/// A value as the exposition formats spell it (`+Inf`, `-Inf`, `NaN`).
fn number(v: f64) -> String {
    if v.is_nan() {
        "NaN".into()
    } else if v == f64::INFINITY {
        "+Inf".into()
    } else if v == f64::NEG_INFINITY {
        "-Inf".into()
    } else {
        format!("{v}")
    }
}

fn flag(b: bool) -> f64 {
    if b {
        1.0
    } else {
        0.0
    }
}

/// σ samples: metres for x, y, z and degrees for the angles (pitch and roll when estimated).
fn sigma_families(out: &mut String, prefix: &str, what: &str, s: Option<&Sigma>) {
    let Some(s) = s else {
        return;
    };
    gauge(
        out,
        &format!("{prefix}_sigma_meters"),
        &format!("Marginal standard deviation of {what}'s camera centre per map axis."),
        |f| {
            for (axis, v) in [("x", s.x), ("y", s.y), ("z", s.z)] {
                f.sample(&format!("{prefix}_sigma_meters"), &[("axis", axis)], v);
            }
        },
    );
    gauge(
        out,
        &format!("{prefix}_sigma_degrees"),
        &format!("Marginal standard deviation of {what}'s angles (pitch and roll when estimated)."),
        |f| {
            let n = format!("{prefix}_sigma_degrees");
            f.sample(&n, &[("axis", "yaw")], s.yaw);
            if let Some(p) = s.pitch {
                f.sample(&n, &[("axis", "pitch")], p);
            }
            if let Some(r) = s.roll {
                f.sample(&n, &[("axis", "roll")], r);
            }
        },
    );
}

/// The status as OpenMetrics text (ending in `# EOF`), `now_unix` being the clock reading in
/// seconds since the Unix epoch (for the pose's age).
pub fn render(s: &Status, now_unix: f64) -> String {
    let mut o = String::new();
    gauge(
        &mut o,
        "infraloc_build_info",
        "The running build: version, architecture and OS (value always 1).",
        |f| {
            f.sample(
                "infraloc_build_info",
                &[
                    ("version", &s.version),
                    ("arch", std::env::consts::ARCH),
                    ("os", std::env::consts::OS),
                ],
                1.0,
            )
        },
    );
    gauge(
        &mut o,
        "infraloc_state",
        "Service state: 1 for the current one (starting, ok, degraded, failed).",
        |f| {
            for st in [State::Starting, State::Ok, State::Degraded, State::Failed] {
                f.sample(
                    "infraloc_state",
                    &[("state", st.name())],
                    flag(s.state == st),
                );
            }
        },
    );
    gauge(
        &mut o,
        "infraloc_uptime_seconds",
        "Seconds since the service started.",
        |f| f.sample("infraloc_uptime_seconds", &[], s.uptime_s),
    );
    gauge(
        &mut o,
        "infraloc_config_reload_failed",
        "1 when the last SIGHUP reload was refused (the running config stays in force).",
        |f| {
            f.sample(
                "infraloc_config_reload_failed",
                &[],
                flag(s.reload_error.is_some()),
            )
        },
    );
    gauge(
        &mut o,
        "infraloc_pose_served",
        "1 when a pose is served.",
        |f| f.sample("infraloc_pose_served", &[], flag(s.served.is_some())),
    );
    if let Some(p) = &s.served {
        if let Some(t) = unix_seconds(&p.timestamp_utc) {
            gauge(
                &mut o,
                "infraloc_pose_timestamp_seconds",
                "When the served pose was computed, seconds since the Unix epoch.",
                |f| f.sample("infraloc_pose_timestamp_seconds", &[], t),
            );
            gauge(
                &mut o,
                "infraloc_pose_age_seconds",
                "Age of the served pose.",
                |f| f.sample("infraloc_pose_age_seconds", &[], (now_unix - t).max(0.0)),
            );
        }
        if let Some(score) = p.score {
            gauge(
                &mut o,
                "infraloc_pose_score",
                "The served pose's score (NMI at the MI optimum).",
                |f| f.sample("infraloc_pose_score", &[], score),
            );
        }
        sigma_families(&mut o, "infraloc_pose", "the served pose", p.sigma.as_ref());
    }
    gauge(
        &mut o,
        "infraloc_job_running",
        "1 for the job running now (localize, drift-check).",
        |f| {
            for job in ["localize", "drift-check"] {
                let on = s.running.as_ref().is_some_and(|r| r.job.name() == job);
                f.sample("infraloc_job_running", &[("job", job)], flag(on));
            }
        },
    );
    gauge(
        &mut o,
        "infraloc_consecutive_failures",
        "Failed localizations since the last successful one.",
        |f| {
            f.sample(
                "infraloc_consecutive_failures",
                &[],
                f64::from(s.failures_in_a_row),
            )
        },
    );
    if let Some(r) = &s.last_result {
        if let Some(t) = unix_seconds(&r.finished_utc) {
            gauge(
                &mut o,
                "infraloc_last_run_timestamp_seconds",
                "When the latest localization finished, seconds since the Unix epoch.",
                |f| f.sample("infraloc_last_run_timestamp_seconds", &[], t),
            );
        }
        gauge(
            &mut o,
            "infraloc_last_run_success",
            "1 when the latest localization computed a pose.",
            |f| f.sample("infraloc_last_run_success", &[], flag(r.ok())),
        );
        gauge(
            &mut o,
            "infraloc_last_run_served",
            "1 when the latest localization's pose is now served.",
            |f| f.sample("infraloc_last_run_served", &[], flag(r.served())),
        );
        gauge(
            &mut o,
            "infraloc_last_run_duration_seconds",
            "Wall time of the latest localization.",
            |f| f.sample("infraloc_last_run_duration_seconds", &[], r.seconds),
        );
        if let RunOutcome::Localized {
            score,
            sigma,
            stages,
            skipped_tiles,
            ..
        } = &r.outcome
        {
            if let Some(score) = score {
                gauge(
                    &mut o,
                    "infraloc_last_run_score",
                    "The latest result's score (NMI at the MI optimum).",
                    |f| f.sample("infraloc_last_run_score", &[], *score),
                );
            }
            sigma_families(
                &mut o,
                "infraloc_last_run",
                "the latest result",
                sigma.as_ref(),
            );
            gauge(
                &mut o,
                "infraloc_last_run_stage_duration_seconds",
                "Wall time of each stage of the latest localization.",
                |f| {
                    for st in stages {
                        f.sample(
                            "infraloc_last_run_stage_duration_seconds",
                            &[("stage", &st.name)],
                            st.seconds,
                        );
                    }
                },
            );
            gauge(
                &mut o,
                "infraloc_last_run_skipped_tiles",
                "Tiles of the cache the latest localization skipped as unreadable.",
                |f| {
                    f.sample(
                        "infraloc_last_run_skipped_tiles",
                        &[],
                        skipped_tiles.len() as f64,
                    )
                },
            );
        }
    }
    if let Some(d) = &s.last_drift_check {
        if let Some(t) = unix_seconds(&d.checked_utc) {
            gauge(
                &mut o,
                "infraloc_drift_check_timestamp_seconds",
                "When the latest drift check ran, seconds since the Unix epoch.",
                |f| f.sample("infraloc_drift_check_timestamp_seconds", &[], t),
            );
        }
        gauge(
            &mut o,
            "infraloc_drift_check_ran",
            "1 when the latest drift check could run (frames and tile available).",
            |f| {
                f.sample(
                    "infraloc_drift_check_ran",
                    &[],
                    flag(matches!(d.outcome, DriftOutcome::Ran(_))),
                )
            },
        );
        gauge(
            &mut o,
            "infraloc_drift_moved",
            "1 when the latest drift check found the camera moved and no re-localization has answered it yet.",
            |f| f.sample("infraloc_drift_moved", &[], flag(d.unresolved_move())),
        );
        if let DriftOutcome::Ran(r) = &d.outcome {
            gauge(
                &mut o,
                "infraloc_drift_offset_meters",
                "Offset of the drift check's MI optimum from the served pose: horizontal distance and height.",
                |f| {
                    f.sample(
                        "infraloc_drift_offset_meters",
                        &[("axis", "horizontal")],
                        r.verdict.shift_m,
                    );
                    f.sample(
                        "infraloc_drift_offset_meters",
                        &[("axis", "z")],
                        r.verdict.dz_m,
                    );
                },
            );
            gauge(
                &mut o,
                "infraloc_drift_offset_degrees",
                "Offset of the drift check's MI optimum from the served pose in yaw.",
                |f| {
                    f.sample(
                        "infraloc_drift_offset_degrees",
                        &[("axis", "yaw")],
                        r.verdict.yaw_deg,
                    )
                },
            );
        }
    }
    o.push_str("# EOF\n");
    o
}

/// The clock now, in seconds since the Unix epoch.
pub(crate) fn now_unix() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs_f64())
        .unwrap_or(0.0)
}

/// Mode of the metrics file: node_exporter runs as another user.
pub(crate) const FILE_MODE: u32 = 0o644;

/// Write the metrics of `s` into `dir` atomically (temp file beside it, fsync, rename).
pub fn write(dir: &Path, s: &Status) -> crate::error::Result<()> {
    crate::persist::write_atomic_mode(
        &file_in(dir),
        render(s, now_unix()).as_bytes(),
        Some(FILE_MODE),
    )
}
