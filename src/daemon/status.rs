//! The service's published state, typed: what the daemon serves in answer to `status` and to
//! `relocalize --wait`, and what `infraloc status` / `infraloc relocalize` read back. One set of
//! serde types on both sides of the control socket, so the client never guesses at a field.
//!
//! The JSON on the wire is what it was when these were built from `serde_json::json!`: the same
//! keys with the same value types (`null` where a value is absent), so scripts reading
//! `infraloc status --json` keep working.

use crate::control::{Accepted, Refusal};
use crate::localize::refine::quality::Sigma;
use crate::map::cache::SkippedTile;
use crate::posefile::PoseFile;
use crate::stage::StageName;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// What the service is doing, as `infraloc status` shows it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum State {
    /// Booting: no pose served yet and the first localization not finished.
    Starting,
    /// A pose is served and the latest localization (or drift check) agreed with it.
    Ok,
    /// A pose is served but the latest attempt failed or the camera looks moved.
    Degraded,
    /// No pose is served and the latest attempt failed.
    Failed,
}

impl State {
    /// Name as printed.
    pub(crate) fn name(self) -> &'static str {
        match self {
            State::Starting => "starting",
            State::Ok => "ok",
            State::Degraded => "degraded",
            State::Failed => "failed",
        }
    }
}

/// The service's status (answer to the `status` request, with `"ok": true` beside it).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Status {
    /// Overall state.
    pub state: State,
    /// One line a technician reads first.
    pub summary: String,
    /// Daemon process id.
    pub pid: u32,
    /// Software version.
    pub version: String,
    /// Config file in use.
    pub config: PathBuf,
    /// Seconds since start.
    pub uptime_s: f64,
    /// The served pose.
    pub served: Option<Served>,
    /// The job running now and its stage.
    pub running: Option<Running>,
    /// The latest localization's result.
    pub last_result: Option<RunResult>,
    /// The latest drift check's result.
    pub last_drift_check: Option<DriftCheck>,
    /// Failed localizations since the last good one.
    pub failures_in_a_row: u32,
    /// Seconds until the next scheduled localization (retry or periodic), if one is scheduled.
    pub next_localize_in_s: Option<f64>,
    /// Seconds until the next drift check, if one is scheduled.
    pub next_drift_check_in_s: Option<f64>,
    /// Why the last SIGHUP reload was refused (the running config stays in force).
    pub reload_error: Option<String>,
    /// The frames of earlier runs stored for pooling, oldest first ([`crate::frames`]).
    #[serde(default)]
    pub stored_frames: Vec<crate::frames::FrameEntry>,
}

/// Summary of the served pose file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Served {
    /// The pose file.
    pub file: PathBuf,
    /// When the pose was computed.
    pub timestamp_utc: String,
    /// Tile it was computed in.
    pub tile_id: String,
    /// The map CRS.
    pub crs: String,
    /// Camera centre in the map CRS, metres.
    pub camera_center: [f64; 3],
    /// Yaw, pitch, roll, degrees.
    pub yaw_pitch_roll_deg: [f64; 3],
    /// The pose store's comparison score (the MI optimum's NMI), when the file has one.
    pub score: Option<f64>,
    /// The pose's marginal σ per axis (the file's `quality.sigma`); `None` for a file without
    /// one (written by an older version, or a hand-made initial pose).
    #[serde(default)]
    pub sigma: Option<Sigma>,
    /// The pose's grade, `precise` or `coarse` (docs/pose.md "Grade").
    #[serde(default = "precise")]
    pub grade: String,
    /// Why it is coarse (its σ over the precise limit), when it is.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub grade_reason: Option<String>,
}

/// The grade of a served pose whose status was written before grades.
fn precise() -> String {
    "precise".into()
}

impl Served {
    /// The summary of pose file `p` stored at `path`.
    pub(crate) fn of(path: &Path, p: &PoseFile) -> Served {
        Served {
            file: path.to_path_buf(),
            timestamp_utc: p.timestamp_utc.clone(),
            tile_id: p.tile_id.clone(),
            crs: p.crs.clone(),
            camera_center: p.camera_center,
            yaw_pitch_roll_deg: p.yaw_pitch_roll_deg,
            score: p.score(),
            sigma: p.sigma(),
            grade: p.grade().to_string(),
            grade_reason: p.grade_reason(),
        }
    }
}

/// A job of the service.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum JobKind {
    /// A localization.
    Localize,
    /// A drift check.
    DriftCheck,
}

impl JobKind {
    /// Name as printed.
    pub(crate) fn name(self) -> &'static str {
        match self {
            JobKind::Localize => "localize",
            JobKind::DriftCheck => "drift-check",
        }
    }
}

/// The job running now.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Running {
    /// Which job.
    pub job: JobKind,
    /// Why a localization runs (boot, scheduled, retry after failure, technician request, …).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub why: Option<String>,
    /// The stage it is in.
    pub stage: StageName,
    /// Seconds since it started.
    pub seconds: f64,
}

/// The answer to `get-pose`: the served pose file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct PoseAnswer {
    /// The pose file as stored.
    pub pose: PoseFile,
}

/// The answer to `validate`: the daemon's config file passed, with these warnings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct Validated {
    /// The config file the daemon read.
    pub config: PathBuf,
    /// What the file's check warns about.
    pub warnings: Vec<String>,
}

/// The refusal of `validate`: the daemon's config file and what is wrong with it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct ConfigRefusal {
    /// The config file the daemon read.
    pub config: PathBuf,
    /// The config error, one line.
    pub error: String,
}

/// The answer to `dump-overlay`; the PNG follows as a frame of its own.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct OverlayAnswer {
    /// When the run whose overlay it is computed its pose.
    pub timestamp_utc: String,
    /// The PNG's length.
    pub bytes: usize,
}

/// The answer to `relocalize` without `wait`: the run is queued.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct Queued {
    /// Always true.
    pub queued: bool,
}

/// The answer to `clear-frames`: how many stored frames were dropped.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct Cleared {
    /// Stored frames dropped.
    pub cleared: usize,
}

/// A final answer of the daemon, whichever request it answers. Each serializes to an object with
/// `"ok"`: the request's answer (or its refusal) as `infraloc` reads it back.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub(crate) enum DaemonAnswer {
    /// `status`.
    Status(Accepted<Box<Status>>),
    /// `get-pose`.
    Pose(Accepted<Box<PoseAnswer>>),
    /// `validate`, the file passed.
    Validated(Accepted<Validated>),
    /// `validate`, the file did not pass (`"ok": false`).
    ConfigRefused(Refused<ConfigRefusal>),
    /// `dump-overlay`.
    Overlay(Accepted<OverlayAnswer>),
    /// `relocalize` without `wait`.
    Queued(Accepted<Queued>),
    /// `clear-frames`.
    Cleared(Accepted<Cleared>),
    /// `relocalize` with `wait`: the run's result (`"ok"` inside).
    Result(Box<RunResult>),
    /// `georef`: the `infraloc.georef.v1` document (docs/georef.md).
    Georef(Accepted<crate::georef::Document>),
    /// Any request not served.
    Refused(Refusal),
}

/// A refusal with fields of its own beside `"ok": false` (its `T` has the `"error"`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) struct Refused<T> {
    ok: bool,
    #[serde(flatten)]
    body: T,
}

impl<T> Refused<T> {
    /// The refusal carrying `body`.
    pub(crate) fn new(body: T) -> Self {
        Refused { ok: false, body }
    }
}

/// One stage's wall time in a [`RunResult`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageTime {
    /// Stage name as the pose file has it.
    pub name: String,
    /// Wall time, seconds.
    pub seconds: f64,
}

/// A localization's result: the status's `last_result` and the answer to
/// `relocalize --wait`. On the wire it carries `"ok"` (whether a pose was computed) and the
/// outcome's fields beside the common ones.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(into = "RunResultWire", try_from = "RunResultWire")]
pub struct RunResult {
    /// When it finished.
    pub finished_utc: String,
    /// How long it took.
    pub seconds: f64,
    /// What came of it.
    pub outcome: RunOutcome,
    /// When each stored frame pooled with the run's own was taken, UTC, newest first (empty: the
    /// run had its own frame only).
    pub pooled_frames: Vec<String>,
}

/// What came of a localization.
#[derive(Debug, Clone, PartialEq)]
pub enum RunOutcome {
    /// A pose was computed; the store served it or kept the served one.
    Localized {
        /// Whether the new pose is now served.
        served: bool,
        /// The pose store's (or the cross-check's) reason.
        decision: String,
        /// Camera centre, map CRS, metres.
        camera_center: [f64; 3],
        /// Yaw, pitch, roll, degrees.
        yaw_pitch_roll_deg: [f64; 3],
        /// The pose's comparison score, if it has one.
        score: Option<f64>,
        /// The pose's marginal σ per axis, when it was estimated.
        sigma: Option<Sigma>,
        /// The pipeline's stages and their wall times.
        stages: Vec<StageTime>,
        /// Tiles of the cache that could not be read and were passed over (a good tile
        /// covered the position).
        skipped_tiles: Vec<SkippedTile>,
    },
    /// No pose: the error, and when the next try is.
    Failed {
        /// The one-line error.
        error: String,
        /// Seconds until the retry.
        retry_in_s: f64,
    },
}

impl RunResult {
    /// Whether a pose was computed.
    pub(crate) fn ok(&self) -> bool {
        matches!(self.outcome, RunOutcome::Localized { .. })
    }

    /// Whether the result is now the served pose.
    pub(crate) fn served(&self) -> bool {
        matches!(self.outcome, RunOutcome::Localized { served: true, .. })
    }

    /// The error, for a failed run.
    pub(crate) fn error(&self) -> Option<&str> {
        match &self.outcome {
            RunOutcome::Failed { error, .. } => Some(error),
            RunOutcome::Localized { .. } => None,
        }
    }
}

/// [`RunResult`] as JSON: every outcome's fields, those of the other outcome absent.
#[derive(Serialize, Deserialize)]
struct RunResultWire {
    ok: bool,
    finished_utc: String,
    seconds: f64,
    served: bool,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    decision: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    camera_center: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    yaw_pitch_roll_deg: Option<[f64; 3]>,
    // Present (possibly null) for a localized run, absent for a failed one.
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        with = "present_or_null"
    )]
    score: Option<Option<f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    sigma: Option<Sigma>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    stages: Option<Vec<StageTime>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    skipped_tiles: Option<Vec<SkippedTile>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    error: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    retry_in_s: Option<f64>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pooled_frames: Vec<String>,
}

/// An optional field whose value may itself be `null`: absent → `None`, `null` →
/// `Some(None)`.
mod present_or_null {
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    pub(super) fn serialize<S: Serializer>(
        v: &Option<Option<f64>>,
        s: S,
    ) -> Result<S::Ok, S::Error> {
        // Only called for `Some` (the field is skipped when `None`).
        v.flatten().serialize(s)
    }

    pub(super) fn deserialize<'de, D: Deserializer<'de>>(
        d: D,
    ) -> Result<Option<Option<f64>>, D::Error> {
        Option::<f64>::deserialize(d).map(Some)
    }
}

impl From<RunResult> for RunResultWire {
    fn from(r: RunResult) -> Self {
        let mut w = RunResultWire {
            ok: r.ok(),
            finished_utc: r.finished_utc,
            seconds: r.seconds,
            served: false,
            decision: None,
            camera_center: None,
            yaw_pitch_roll_deg: None,
            score: None,
            sigma: None,
            stages: None,
            skipped_tiles: None,
            error: None,
            retry_in_s: None,
            pooled_frames: r.pooled_frames,
        };
        match r.outcome {
            RunOutcome::Localized {
                served,
                decision,
                camera_center,
                yaw_pitch_roll_deg,
                score,
                sigma,
                stages,
                skipped_tiles,
            } => {
                w.served = served;
                w.decision = Some(decision);
                w.camera_center = Some(camera_center);
                w.yaw_pitch_roll_deg = Some(yaw_pitch_roll_deg);
                w.score = Some(score);
                w.sigma = sigma;
                w.stages = Some(stages);
                w.skipped_tiles = Some(skipped_tiles);
            }
            RunOutcome::Failed { error, retry_in_s } => {
                w.error = Some(error);
                w.retry_in_s = Some(retry_in_s);
            }
        }
        w
    }
}

impl TryFrom<RunResultWire> for RunResult {
    type Error = String;

    fn try_from(w: RunResultWire) -> Result<Self, String> {
        let missing = |k: &str| {
            format!(
                "a {} run result without \"{k}\"",
                if w.ok { "successful" } else { "failed" }
            )
        };
        let outcome = if w.ok {
            RunOutcome::Localized {
                served: w.served,
                decision: w.decision.clone().ok_or_else(|| missing("decision"))?,
                camera_center: w.camera_center.ok_or_else(|| missing("camera_center"))?,
                yaw_pitch_roll_deg: w
                    .yaw_pitch_roll_deg
                    .ok_or_else(|| missing("yaw_pitch_roll_deg"))?,
                score: w.score.ok_or_else(|| missing("score"))?,
                sigma: w.sigma,
                stages: w.stages.clone().ok_or_else(|| missing("stages"))?,
                // A daemon from before the key skipped nothing it could report.
                skipped_tiles: w.skipped_tiles.clone().unwrap_or_default(),
            }
        } else {
            RunOutcome::Failed {
                error: w.error.clone().ok_or_else(|| missing("error"))?,
                retry_in_s: w.retry_in_s.ok_or_else(|| missing("retry_in_s"))?,
            }
        };
        Ok(RunResult {
            finished_utc: w.finished_utc,
            seconds: w.seconds,
            outcome,
            pooled_frames: w.pooled_frames,
        })
    }
}

pub use infraloc_core::localize::refine::drift::{DriftSearch, DriftVerdict, Optimum};

/// The status's record of the latest drift check.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DriftCheck {
    /// When it ran.
    pub checked_utc: String,
    /// What it found, or why it could not run.
    #[serde(flatten)]
    pub outcome: DriftOutcome,
    /// For a camera found moved: the re-localization that answered it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub resolved: Option<String>,
}

/// A drift check's outcome. On the wire a check that could not run has `"moved": null`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum DriftOutcome {
    /// The search ran.
    Ran(DriftSearch),
    /// It could not run (no frames, no tile, …).
    NotRun {
        /// Always `null`: neither moved nor steady.
        moved: (),
        /// Why.
        error: String,
    },
}

impl DriftCheck {
    /// Whether the check found the camera moved and no re-localization has answered it yet.
    pub(crate) fn unresolved_move(&self) -> bool {
        matches!(&self.outcome, DriftOutcome::Ran(s) if s.verdict.moved) && self.resolved.is_none()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::posefile::PoseQuality;

    fn localized(sigma: Option<Sigma>, skipped: Vec<SkippedTile>) -> RunResult {
        RunResult {
            finished_utc: "2026-01-02T03:04:05Z".into(),
            seconds: 12.5,
            outcome: RunOutcome::Localized {
                served: true,
                decision: "first pose".into(),
                camera_center: [1.0, 2.0, 3.0],
                yaw_pitch_roll_deg: [10.0, -80.0, 0.5],
                score: Some(0.12),
                sigma,
                stages: vec![StageTime {
                    name: "mi".into(),
                    seconds: 4.0,
                }],
                skipped_tiles: skipped,
            },
            pooled_frames: vec!["2026-01-02T02:00:00Z".into()],
        }
    }

    #[test]
    fn a_run_result_keeps_sigma_and_skipped_tiles_over_the_wire() {
        let sigma = Sigma {
            x: 0.012,
            y: 0.02,
            z: 0.005,
            yaw: 0.04,
            pitch: None,
            roll: Some(0.3),
        };
        let skipped = vec![SkippedTile {
            dir: "/var/cache/tiles/aaa".into(),
            reason: "tile: /var/cache/tiles/aaa/tile.toml: truncated".into(),
        }];
        let r = localized(Some(sigma), skipped.clone());
        let v = serde_json::to_value(&r).unwrap();
        assert_eq!(v["sigma"]["x"], 0.012);
        assert_eq!(v["skipped_tiles"][0]["dir"], "/var/cache/tiles/aaa");
        let back: RunResult = serde_json::from_value(v).unwrap();
        assert_eq!(back, r);
        // A pose without σ and a daemon that predates `skipped_tiles` still parse.
        let mut v = serde_json::to_value(localized(None, vec![])).unwrap();
        assert!(v.get("sigma").is_none(), "{v}");
        v.as_object_mut().unwrap().remove("skipped_tiles");
        let back: RunResult = serde_json::from_value(v).unwrap();
        assert_eq!(back, localized(None, vec![]));
    }

    #[test]
    fn served_reads_sigma_from_the_pose_files_quality_block() {
        let pose = crate::pose::CamFromMap::from_rows(
            [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            [0.0, 0.0, 0.0],
        );
        let mut p = PoseFile::new(&pose, crate::map::Crs::Local, "t", "2026".into());
        assert_eq!(Served::of(Path::new("p.json"), &p).sigma, None);
        p.quality = PoseQuality::from_value(serde_json::json!({"score": 0.1,
            "sigma": {"x": 0.01, "y": 0.02, "z": 0.03, "yaw": 0.1}}));
        let s = Served::of(Path::new("p.json"), &p).sigma.unwrap();
        assert_eq!((s.x, s.y, s.z, s.yaw), (0.01, 0.02, 0.03, 0.1));
        assert_eq!((s.pitch, s.roll), (None, None));
        // A malformed block is "no σ", not an error.
        p.quality = PoseQuality::from_value(serde_json::json!({"sigma": {"x": "wide"}}));
        assert_eq!(Served::of(Path::new("p.json"), &p).sigma, None);
    }
}
