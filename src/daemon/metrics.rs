//! The service's status as OpenMetrics text, for Prometheus through node_exporter's textfile
//! collector (`[daemon] metrics-dir`) and for `infraloc status --format openmetrics`. One
//! rendering, [`render`], serves both, so what a scrape sees is what a technician sees.
//!
//! Only gauges are used, so the text is valid both as OpenMetrics and as the Prometheus text
//! format node_exporter parses (it reads the closing `# EOF` as a comment). Values that do not
//! exist (no pose served, no run yet, a pose without σ) are left out rather than written as
//! `NaN`, so an alert on them can use `absent()`.

use super::status::{DriftOutcome, DriftSearch, RunOutcome, StageTime, State, Status};
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

/// The kind of a metric family, as its `# TYPE` line names it.
#[derive(Debug, Clone, Copy)]
enum Kind {
    /// A value that goes up and down.
    Gauge,
}

impl Kind {
    fn name(self) -> &'static str {
        match self {
            Kind::Gauge => "gauge",
        }
    }
}

/// One sample of a family: its labels (`(name, value)` pairs) and value.
struct Sample {
    labels: Vec<(&'static str, String)>,
    value: f64,
}

impl Sample {
    /// A sample without labels.
    fn bare(value: f64) -> Vec<Sample> {
        vec![Sample {
            labels: Vec::new(),
            value,
        }]
    }

    /// One sample per `(label value, value)`, all under the label `name`.
    fn by<'a>(name: &'static str, values: impl IntoIterator<Item = (&'a str, f64)>) -> Vec<Sample> {
        values
            .into_iter()
            .map(|(v, value)| Sample {
                labels: vec![(name, v.to_string())],
                value,
            })
            .collect()
    }
}

/// The samples of a family read from the status and the clock (seconds since the Unix epoch);
/// `None` leaves the whole family out, `Some` of no samples writes its metadata alone.
type Read = fn(&Status, f64) -> Option<Vec<Sample>>;

/// A metric family: what its metadata says and how its samples are read from the status.
struct Metric {
    name: &'static str,
    help: &'static str,
    kind: Kind,
    read: Read,
}

/// The families in the order they are written.
const METRICS: &[Metric] = &[
    Metric {
        name: "infraloc_build_info",
        help: "The running build: version, architecture and OS (value always 1).",
        kind: Kind::Gauge,
        read: |s, _| {
            Some(vec![Sample {
                labels: vec![
                    ("version", s.version.clone()),
                    ("arch", std::env::consts::ARCH.into()),
                    ("os", std::env::consts::OS.into()),
                ],
                value: 1.0,
            }])
        },
    },
    Metric {
        name: "infraloc_state",
        help: "Service state: 1 for the current one (starting, ok, degraded, failed).",
        kind: Kind::Gauge,
        read: |s, _| {
            let states = [State::Starting, State::Ok, State::Degraded, State::Failed];
            Some(Sample::by(
                "state",
                states.map(|st| (st.name(), flag(s.state == st))),
            ))
        },
    },
    Metric {
        name: "infraloc_uptime_seconds",
        help: "Seconds since the service started.",
        kind: Kind::Gauge,
        read: |s, _| Some(Sample::bare(s.uptime_s)),
    },
    Metric {
        name: "infraloc_config_reload_failed",
        help: "1 when the last SIGHUP reload was refused (the running config stays in force).",
        kind: Kind::Gauge,
        read: |s, _| Some(Sample::bare(flag(s.reload_error.is_some()))),
    },
    Metric {
        name: "infraloc_pose_served",
        help: "1 when a pose is served.",
        kind: Kind::Gauge,
        read: |s, _| Some(Sample::bare(flag(s.served.is_some()))),
    },
    Metric {
        name: "infraloc_pose_timestamp_seconds",
        help: "When the served pose was computed, seconds since the Unix epoch.",
        kind: Kind::Gauge,
        read: |s, _| served_at(s).map(Sample::bare),
    },
    Metric {
        name: "infraloc_pose_age_seconds",
        help: "Age of the served pose.",
        kind: Kind::Gauge,
        read: |s, now| served_at(s).map(|t| Sample::bare((now - t).max(0.0))),
    },
    Metric {
        name: "infraloc_pose_score",
        help: "The served pose's score (NMI at the MI optimum).",
        kind: Kind::Gauge,
        read: |s, _| s.served.as_ref()?.score.map(Sample::bare),
    },
    Metric {
        name: "infraloc_pose_sigma_meters",
        help: "Marginal standard deviation of the served pose's camera centre per map axis.",
        kind: Kind::Gauge,
        read: |s, _| sigma_meters(s.served.as_ref()?.sigma.as_ref()),
    },
    Metric {
        name: "infraloc_pose_sigma_degrees",
        help: "Marginal standard deviation of the served pose's angles (pitch and roll when estimated).",
        kind: Kind::Gauge,
        read: |s, _| sigma_degrees(s.served.as_ref()?.sigma.as_ref()),
    },
    Metric {
        name: "infraloc_pose_grade",
        help: "1 for the served pose's grade (precise, coarse); 0 for the other.",
        kind: Kind::Gauge,
        read: |s, _| {
            let g = s.served.as_ref()?.grade.as_str();
            Some(Sample::by(
                "grade",
                ["precise", "coarse"].map(|n| (n, flag(g == n))),
            ))
        },
    },
    Metric {
        name: "infraloc_job_running",
        help: "1 for the job running now (localize, drift-check).",
        kind: Kind::Gauge,
        read: |s, _| {
            let on = |job: &str| s.running.as_ref().is_some_and(|r| r.job.name() == job);
            Some(Sample::by(
                "job",
                ["localize", "drift-check"].map(|job| (job, flag(on(job)))),
            ))
        },
    },
    Metric {
        name: "infraloc_stored_frames",
        help: "Frames of earlier runs stored for pooling into later ones.",
        kind: Kind::Gauge,
        read: |s, _| Some(Sample::bare(s.stored_frames.len() as f64)),
    },
    Metric {
        name: "infraloc_last_run_pooled_frames",
        help: "Stored frames the latest localization pooled with its own.",
        kind: Kind::Gauge,
        read: |s, _| Some(Sample::bare(s.last_result.as_ref()?.pooled_frames.len() as f64)),
    },
    Metric {
        name: "infraloc_consecutive_failures",
        help: "Failed localizations since the last successful one.",
        kind: Kind::Gauge,
        read: |s, _| Some(Sample::bare(f64::from(s.failures_in_a_row))),
    },
    Metric {
        name: "infraloc_last_run_timestamp_seconds",
        help: "When the latest localization finished, seconds since the Unix epoch.",
        kind: Kind::Gauge,
        read: |s, _| unix_seconds(&s.last_result.as_ref()?.finished_utc).map(Sample::bare),
    },
    Metric {
        name: "infraloc_last_run_success",
        help: "1 when the latest localization computed a pose.",
        kind: Kind::Gauge,
        read: |s, _| Some(Sample::bare(flag(s.last_result.as_ref()?.ok()))),
    },
    Metric {
        name: "infraloc_last_run_served",
        help: "1 when the latest localization's pose is now served.",
        kind: Kind::Gauge,
        read: |s, _| Some(Sample::bare(flag(s.last_result.as_ref()?.served()))),
    },
    Metric {
        name: "infraloc_last_run_duration_seconds",
        help: "Wall time of the latest localization.",
        kind: Kind::Gauge,
        read: |s, _| Some(Sample::bare(s.last_result.as_ref()?.seconds)),
    },
    Metric {
        name: "infraloc_last_run_score",
        help: "The latest result's score (NMI at the MI optimum).",
        kind: Kind::Gauge,
        read: |s, _| localized(s)?.score.map(Sample::bare),
    },
    Metric {
        name: "infraloc_last_run_sigma_meters",
        help: "Marginal standard deviation of the latest result's camera centre per map axis.",
        kind: Kind::Gauge,
        read: |s, _| sigma_meters(localized(s)?.sigma),
    },
    Metric {
        name: "infraloc_last_run_sigma_degrees",
        help: "Marginal standard deviation of the latest result's angles (pitch and roll when estimated).",
        kind: Kind::Gauge,
        read: |s, _| sigma_degrees(localized(s)?.sigma),
    },
    Metric {
        name: "infraloc_last_run_stage_duration_seconds",
        help: "Wall time of each stage of the latest localization.",
        kind: Kind::Gauge,
        read: |s, _| {
            let stages = localized(s)?.stages;
            Some(Sample::by(
                "stage",
                stages.iter().map(|st| (st.name.as_str(), st.seconds)),
            ))
        },
    },
    Metric {
        name: "infraloc_last_run_skipped_tiles",
        help: "Tiles of the cache the latest localization skipped as unreadable.",
        kind: Kind::Gauge,
        read: |s, _| Some(Sample::bare(localized(s)?.skipped_tiles as f64)),
    },
    Metric {
        name: "infraloc_drift_check_timestamp_seconds",
        help: "When the latest drift check ran, seconds since the Unix epoch.",
        kind: Kind::Gauge,
        read: |s, _| unix_seconds(&s.last_drift_check.as_ref()?.checked_utc).map(Sample::bare),
    },
    Metric {
        name: "infraloc_drift_check_ran",
        help: "1 when the latest drift check could run (frames and tile available).",
        kind: Kind::Gauge,
        read: |s, _| {
            let d = s.last_drift_check.as_ref()?;
            Some(Sample::bare(flag(matches!(d.outcome, DriftOutcome::Ran(_)))))
        },
    },
    Metric {
        name: "infraloc_drift_moved",
        help: "1 when the latest drift check found the camera moved and no re-localization has answered it yet.",
        kind: Kind::Gauge,
        read: |s, _| Some(Sample::bare(flag(s.last_drift_check.as_ref()?.unresolved_move()))),
    },
    Metric {
        name: "infraloc_drift_offset_meters",
        help: "Offset of the drift check's MI optimum from the served pose: horizontal distance and height.",
        kind: Kind::Gauge,
        read: |s, _| {
            let v = &drift_search(s)?.verdict;
            Some(Sample::by("axis", [("horizontal", v.shift_m), ("z", v.dz_m)]))
        },
    },
    Metric {
        name: "infraloc_drift_offset_degrees",
        help: "Offset of the drift check's MI optimum from the served pose in yaw.",
        kind: Kind::Gauge,
        read: |s, _| Some(Sample::by("axis", [("yaw", drift_search(s)?.verdict.yaw_deg)])),
    },
];

/// When the served pose was computed, seconds since the Unix epoch.
fn served_at(s: &Status) -> Option<f64> {
    unix_seconds(&s.served.as_ref()?.timestamp_utc)
}

/// What the metrics read of a latest run that computed a pose.
struct Localized<'a> {
    score: Option<f64>,
    sigma: Option<&'a Sigma>,
    stages: &'a [StageTime],
    skipped_tiles: usize,
}

/// The latest run, when it computed a pose.
fn localized(s: &Status) -> Option<Localized<'_>> {
    match &s.last_result.as_ref()?.outcome {
        RunOutcome::Localized {
            score,
            sigma,
            stages,
            skipped_tiles,
            ..
        } => Some(Localized {
            score: *score,
            sigma: sigma.as_ref(),
            stages,
            skipped_tiles: skipped_tiles.len(),
        }),
        RunOutcome::Failed { .. } => None,
    }
}

/// The latest drift check's search, when it ran.
fn drift_search(s: &Status) -> Option<&DriftSearch> {
    match &s.last_drift_check.as_ref()?.outcome {
        DriftOutcome::Ran(r) => Some(r),
        _ => None,
    }
}

/// σ of the camera centre in metres per map axis.
fn sigma_meters(s: Option<&Sigma>) -> Option<Vec<Sample>> {
    let s = s?;
    Some(Sample::by("axis", [("x", s.x), ("y", s.y), ("z", s.z)]))
}

/// σ of the angles in degrees: yaw, then pitch and roll when estimated.
fn sigma_degrees(s: Option<&Sigma>) -> Option<Vec<Sample>> {
    let s = s?;
    let tilt = [("pitch", s.pitch), ("roll", s.roll)];
    let tilt = tilt.into_iter().filter_map(|(a, v)| Some((a, v?)));
    Some(Sample::by(
        "axis",
        std::iter::once(("yaw", s.yaw)).chain(tilt),
    ))
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

/// Write one sample line of family `name`.
fn write_sample(out: &mut String, name: &str, s: &Sample) {
    out.push_str(name);
    if !s.labels.is_empty() {
        out.push('{');
        for (i, (k, val)) in s.labels.iter().enumerate() {
            if i > 0 {
                out.push(',');
            }
            let _ = write!(out, "{k}=\"{}\"", escape(val));
        }
        out.push('}');
    }
    let _ = writeln!(out, " {}", number(s.value));
}

/// The status as OpenMetrics text (ending in `# EOF`), `now_unix` being the clock reading in
/// seconds since the Unix epoch (for the pose's age): each family of [`METRICS`] whose samples
/// the status has, its metadata, then its samples.
pub fn render(s: &Status, now_unix: f64) -> String {
    let mut o = String::new();
    for m in METRICS {
        let Some(samples) = (m.read)(s, now_unix) else {
            continue;
        };
        let _ = writeln!(o, "# HELP {} {}", m.name, m.help);
        let _ = writeln!(o, "# TYPE {} {}", m.name, m.kind.name());
        for sample in &samples {
            write_sample(&mut o, m.name, sample);
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
