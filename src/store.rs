//! The pose store (I/O shell): the pose served to the detection pipeline plus a history of the last
//! results, in the service's state directory.
//!
//! `pose.json` is replaced only atomically (`crate::persist::write_atomic`) and only by a result
//! that is `status = "ok"` and not worse than the served one (unless forced: by the technician,
//! or by the drift check that found the camera moved), so a failed re-localization never costs
//! the node its last good pose. Grades come first: a precise result replaces a coarse pose, a
//! coarse result never replaces a precise one; within a grade, quality is compared through
//! `quality.score` (higher is better; the pipeline documents what it puts there).

use crate::error::{Error, Result};
use crate::localize::refine::verdict::rank_of;
use crate::persist::write_atomic;
use crate::posefile::{PoseFile, SCHEMA_V1};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// File name of the served pose.
pub(crate) const POSE_FILE: &str = "pose.json";
/// File name of the history.
pub(crate) const HISTORY_FILE: &str = "history.json";
/// Results kept in the history by default.
pub(crate) const DEFAULT_HISTORY_LEN: usize = 50;
/// A new result may score this much lower than the served one and still replace it: re-running on
/// a new frame jitters the score, and a camera that was knocked must be able to re-register.
pub(crate) const SCORE_TOLERANCE: f64 = 0.05;

/// One history entry.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HistoryEntry {
    /// When the result was produced (from the pose file).
    pub timestamp_utc: String,
    /// Result status (`ok` or the failure).
    pub status: String,
    /// `quality.score` of the result, if any.
    pub score: Option<f64>,
    /// Camera centre of the result (none for a run that failed before it had a pose).
    pub camera_center: Option<[f64; 3]>,
    /// Whether it became the served pose.
    pub accepted: bool,
    /// Why it was (not) accepted.
    pub reason: String,
    /// The result's marginal σ per axis, when it has one: how σ changes over the runs (the
    /// node's pooled frames of earlier hours narrow it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sigma: Option<crate::localize::refine::quality::Sigma>,
    /// The result's grade (`precise` or `coarse`), when it made a pose.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub grade: Option<String>,
}

/// What [`PoseStore::offer`] decided.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Decision {
    /// The result is now the served pose.
    Replaced(String),
    /// The served pose was kept; the reason says why.
    Kept(String),
}

/// A pose store rooted at a directory.
#[derive(Debug, Clone)]
pub struct PoseStore {
    pose: PathBuf,
    history: PathBuf,
    history_len: usize,
}

impl PoseStore {
    /// A store in `dir` (which must exist) keeping `history_len` entries.
    pub fn new(dir: &Path, history_len: usize) -> Self {
        Self::at(&dir.join(POSE_FILE), history_len)
    }

    /// A store serving `pose` (the configured `[output] pose`), its history in [`HISTORY_FILE`]
    /// in the same directory (which must exist: the rename that publishes a pose cannot cross
    /// directories).
    pub(crate) fn at(pose: &Path, history_len: usize) -> Self {
        PoseStore {
            pose: pose.to_path_buf(),
            history: pose.with_file_name(HISTORY_FILE),
            history_len: history_len.max(1),
        }
    }

    /// Path of the served pose file.
    pub(crate) fn pose_path(&self) -> PathBuf {
        self.pose.clone()
    }

    /// The served pose, `None` if none was ever written. A file that exists but cannot be read is
    /// an error naming it (the caller keeps running without a pose rather than inventing one).
    pub fn current(&self) -> Result<Option<PoseFile>> {
        let p = self.pose_path();
        let text = match std::fs::read_to_string(&p) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(Error::io(&p, e)),
        };
        let f: PoseFile = serde_json::from_str(&text)
            .map_err(|e| Error::input(&p, format!("unreadable pose file: {e}")))?;
        if f.schema != SCHEMA_V1 {
            return Err(Error::input(
                &p,
                format!("schema {:?}, expected {SCHEMA_V1:?}", f.schema),
            ));
        }
        Ok(Some(f))
    }

    /// The history, oldest first (empty if none).
    pub fn history(&self) -> Result<Vec<HistoryEntry>> {
        let p = &self.history;
        match std::fs::read_to_string(p) {
            Ok(t) => serde_json::from_str(&t)
                .map_err(|e| Error::input(p, format!("unreadable history: {e}"))),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(Vec::new()),
            Err(e) => Err(Error::io(p, e)),
        }
    }

    /// Offer a new result. It replaces the served pose if it is `ok` and of a better grade
    /// (precise over coarse), or of the same grade and not worse than the served one by more than
    /// `SCORE_TOLERANCE`, or if `force` is set (the technician's override, or the drift check's
    /// finding that the camera moved; a failed result is never served even then). The history
    /// records it either way.
    pub fn offer(&self, candidate: &PoseFile, force: bool) -> Result<Decision> {
        // An unreadable served pose must not block a good new one: treat it as absent, and say so.
        let (current, unreadable) = match self.current() {
            Ok(c) => (c, None),
            Err(e) => (None, Some(e.to_string())),
        };
        let decision = if candidate.status != "ok" {
            Decision::Kept(format!("result status {:?} is not ok", candidate.status))
        } else if force {
            Decision::Replaced("forced by technician".into())
        } else {
            match current.as_ref() {
                None => Decision::Replaced(match unreadable {
                    Some(e) => format!("served pose unreadable ({e}); replaced"),
                    None => "first pose".into(),
                }),
                Some(cur) if cur.status != "ok" => {
                    Decision::Replaced("served pose was not ok".into())
                }
                Some(cur) if candidate.grade() != cur.grade() => {
                    if rank_of(candidate.grade()) > rank_of(cur.grade()) {
                        Decision::Replaced(format!(
                            "{} replaces the served {} pose",
                            candidate.grade(),
                            cur.grade()
                        ))
                    } else {
                        Decision::Kept(format!(
                            "a {} result never replaces the served {} pose",
                            candidate.grade(),
                            cur.grade()
                        ))
                    }
                }
                Some(cur) => match (candidate.score(), cur.score()) {
                    (Some(new), Some(old)) if new < old - SCORE_TOLERANCE => Decision::Kept(
                        format!("quality score {new:.3} < served {old:.3} − {SCORE_TOLERANCE}"),
                    ),
                    _ => Decision::Replaced("quality not worse than served".into()),
                },
            }
        };
        if let Decision::Replaced(_) = decision {
            write_atomic(&self.pose_path(), candidate.to_json().as_bytes())?;
        }
        let (accepted, reason) = match &decision {
            Decision::Replaced(r) => (true, r.clone()),
            Decision::Kept(r) => (false, r.clone()),
        };
        self.append(HistoryEntry {
            timestamp_utc: candidate.timestamp_utc.clone(),
            status: candidate.status.clone(),
            score: candidate.score(),
            camera_center: Some(candidate.camera_center),
            accepted,
            reason,
            sigma: candidate.sigma(),
            grade: Some(candidate.grade().to_string()),
        })?;
        Ok(decision)
    }

    /// Record an ok result that the caller decided not to serve (`why`), leaving the served pose.
    pub(crate) fn record_kept(&self, candidate: &PoseFile, why: &str) -> Result<()> {
        self.append(HistoryEntry {
            timestamp_utc: candidate.timestamp_utc.clone(),
            status: candidate.status.clone(),
            score: candidate.score(),
            camera_center: Some(candidate.camera_center),
            accepted: false,
            reason: why.to_string(),
            sigma: candidate.sigma(),
            grade: Some(candidate.grade().to_string()),
        })
    }

    /// Record a run that failed before it produced a pose (`status` is its one-line reason). The
    /// served pose is not touched.
    pub(crate) fn record_failure(&self, timestamp_utc: &str, status: &str) -> Result<()> {
        self.append(HistoryEntry {
            timestamp_utc: timestamp_utc.to_string(),
            status: status.to_string(),
            score: None,
            camera_center: None,
            accepted: false,
            reason: "localization failed; served pose kept".into(),
            sigma: None,
            grade: None,
        })
    }

    fn append(&self, entry: HistoryEntry) -> Result<()> {
        // A corrupt history is rebuilt rather than blocking the pose.
        let mut hist = self.history().unwrap_or_default();
        hist.push(entry);
        let excess = hist.len().saturating_sub(self.history_len);
        hist.drain(..excess);
        let text = serde_json::to_string_pretty(&hist).map_err(|e| Error::Encode(e.into()))?;
        write_atomic(&self.history, text.as_bytes())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::Crs;
    use crate::pose::CamFromMap;
    use crate::posefile::PoseQuality;
    use nalgebra::Point3;

    fn pose(status: &str, score: f64, x: f64) -> PoseFile {
        let p = CamFromMap::from_center_ypr(&Point3::new(x, 2.0, 8.0), 0.3, 0.0, 0.0);
        let mut f = PoseFile::new(&p, Crs::Epsg(32617), "t", "2026-11-21T12:00:00Z".into());
        f.status = status.into();
        f.quality = PoseQuality {
            score: Some(score),
            ..Default::default()
        };
        f
    }

    #[test]
    fn failed_or_worse_results_keep_the_good_pose() {
        let d = tempfile::tempdir().unwrap();
        let s = PoseStore::new(d.path(), 3);
        assert_eq!(s.current().unwrap(), None);
        assert!(matches!(
            s.offer(&pose("ok", 0.8, 1.0), false).unwrap(),
            Decision::Replaced(_)
        ));
        assert!(matches!(
            s.offer(&pose("pnp: 7 inliers < 12 required", 0.0, 5.0), false)
                .unwrap(),
            Decision::Kept(_)
        ));
        assert!(matches!(
            s.offer(&pose("ok", 0.5, 5.0), false).unwrap(),
            Decision::Kept(_)
        ));
        assert!((s.current().unwrap().unwrap().camera_center[0] - 1.0).abs() < 1e-9);
        // Slightly lower score (jitter) replaces; forced replaces; forced failure still does not.
        assert!(matches!(
            s.offer(&pose("ok", 0.78, 2.0), false).unwrap(),
            Decision::Replaced(_)
        ));
        assert!(matches!(
            s.offer(&pose("ok", 0.1, 3.0), true).unwrap(),
            Decision::Replaced(_)
        ));
        assert!(matches!(
            s.offer(&pose("mi: ambiguous", 0.0, 9.0), true).unwrap(),
            Decision::Kept(_)
        ));
        assert!((s.current().unwrap().unwrap().camera_center[0] - 3.0).abs() < 1e-9);
        let h = s.history().unwrap();
        assert_eq!(h.len(), 3, "history is capped");
        assert!(!h[2].accepted && h[2].reason.contains("not ok"));
    }

    /// A coarse first result is served; a precise one replaces it whatever its score; a coarse
    /// one then never replaces the precise pose, unless forced (the drift check's move, or the
    /// technician); within a grade the score decides.
    #[test]
    fn grades_come_before_scores() {
        let graded = |grade: &str, score: f64, x: f64| {
            let mut f = pose("ok", score, x);
            f.quality.grade = Some(grade.into());
            f
        };
        let d = tempfile::tempdir().unwrap();
        let s = PoseStore::new(d.path(), 10);
        let replaced =
            |f: &PoseFile, force: bool| matches!(s.offer(f, force).unwrap(), Decision::Replaced(_));
        assert!(replaced(&graded("coarse", 0.8, 1.0), false));
        assert_eq!(s.current().unwrap().unwrap().grade(), "coarse");
        assert!(replaced(&graded("precise", 0.2, 2.0), false));
        assert!(!replaced(&graded("coarse", 0.9, 3.0), false));
        assert!(replaced(&graded("precise", 0.19, 4.0), false));
        assert!(!replaced(&graded("precise", 0.1, 5.0), false));
        assert!((s.current().unwrap().unwrap().camera_center[0] - 4.0).abs() < 1e-9);
        assert!(replaced(&graded("coarse", 0.1, 6.0), true));
        let h = s.history().unwrap();
        assert!(
            h[2].reason
                .contains("a coarse result never replaces the served precise pose"),
            "{:?}",
            h[2]
        );
        assert_eq!(h[2].grade.as_deref(), Some("coarse"));
        // A file written before grades is precise.
        assert_eq!(pose("ok", 0.5, 0.0).grade(), "precise");
    }

    #[test]
    fn corrupt_served_pose_is_reported_and_replaceable() {
        let d = tempfile::tempdir().unwrap();
        let s = PoseStore::new(d.path(), 5);
        std::fs::write(s.pose_path(), "{ truncated").unwrap();
        let e = s.current().unwrap_err().to_string();
        assert!(e.contains("pose.json") && e.contains("unreadable"), "{e}");
        assert!(
            matches!(s.offer(&pose("ok", 0.2, 1.0), false).unwrap(), Decision::Replaced(r) if r.contains("unreadable"))
        );
        assert!(s.current().unwrap().is_some());
    }
}
