//! The pose file read by the detection pipeline: `infraloc.pose.v1` JSON (docs/interfaces.md, "Pose file").
//!
//! Writing always emits every required key in every representation (matrix, rvec, quaternion,
//! yaw/pitch/roll) derived from one [`CamFromMap`], so they cannot disagree. Reading needs only
//! `rotation_cam_from_map` + `translation_cam_from_map`, so a simulator `truth.json` or a
//! hand-written initial pose is accepted too.

use crate::error::{Error, Result};
use crate::geo::georef::PoseCovariance;
use crate::geo::Crs;
use crate::pose::CamFromMap;
use crate::pose::Sigma;
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::path::Path;

/// Schema identifier of the pose file.
pub const SCHEMA_V1: &str = "infraloc.pose.v1";

/// Software block of the pose file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Software {
    /// Crate version that wrote the file.
    pub version: String,
}

impl Default for Software {
    fn default() -> Self {
        Software {
            version: env!("CARGO_PKG_VERSION").to_string(),
        }
    }
}

/// The full `infraloc.pose.v1` document.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PoseFile {
    /// Always `SCHEMA_V1`.
    pub schema: String,
    /// `"ok"` for a pose the pipeline may use; other values say why not.
    pub status: String,
    /// When the pose was computed, ISO 8601 UTC.
    pub timestamp_utc: String,
    /// Map CRS (`EPSG:N` or `LOCAL`).
    pub crs: String,
    /// Tile the pose was computed against.
    pub tile_id: String,
    /// Camera centre in the map frame.
    pub camera_center: [f64; 3],
    /// `R` of `X_c = R·X_w + t`, row-major.
    pub rotation_cam_from_map: [[f64; 3]; 3],
    /// `t` of `X_c = R·X_w + t`.
    pub translation_cam_from_map: [f64; 3],
    /// OpenCV rotation vector of `R`.
    pub rvec_cam_from_map: [f64; 3],
    /// Quaternion of `Rᵀ` (map ← camera), x y z w.
    pub quaternion_map_from_cam_xyzw: [f64; 4],
    /// Yaw, pitch, roll in degrees (convention in [`crate::pose`]).
    pub yaw_pitch_roll_deg: [f64; 3],
    /// Camera intrinsics used (the native table, `model` first).
    pub intrinsics: Value,
    /// Quality figures of the result (a file without a `quality` object reads as an empty one).
    #[serde(default)]
    pub quality: PoseQuality,
    /// Per-stage records (`prior`, `pnp`, `mi`, …).
    pub stages: Vec<Value>,
    /// Who wrote it.
    pub software: Software,
    /// Any further keys (kept on read-modify-write).
    #[serde(flatten)]
    pub extra: serde_json::Map<String, Value>,
}

impl PoseFile {
    /// Build a document from a pose; representation keys are all derived from `pose`.
    pub fn new(pose: &CamFromMap, crs: Crs, tile_id: &str, timestamp_utc: String) -> Self {
        let (y, p, r) = pose.yaw_pitch_roll();
        PoseFile {
            schema: SCHEMA_V1.into(),
            status: "ok".into(),
            timestamp_utc,
            crs: crs.to_string(),
            tile_id: tile_id.into(),
            camera_center: pose.center().coords.into(),
            rotation_cam_from_map: pose.rotation_rows(),
            translation_cam_from_map: pose.translation.into(),
            rvec_cam_from_map: pose.rvec().into(),
            quaternion_map_from_cam_xyzw: pose.quaternion_map_from_cam_xyzw(),
            yaw_pitch_roll_deg: [y.to_degrees(), p.to_degrees(), r.to_degrees()],
            intrinsics: Value::Null,
            quality: PoseQuality::default(),
            stages: Vec::new(),
            software: Software::default(),
            extra: Default::default(),
        }
    }

    /// The pose this document describes.
    pub fn pose(&self) -> CamFromMap {
        CamFromMap::from_rows(self.rotation_cam_from_map, self.translation_cam_from_map)
    }

    /// The marginal σ per axis of `quality.sigma`, if the file has a well-formed one.
    pub fn sigma(&self) -> Option<Sigma> {
        self.quality.sigma
    }

    /// The pose's covariance from `quality.covariance` (`axes` and `matrix`, docs/pose.md
    /// "Uncertainty"): `Ok(None)` when the file has none, an error naming the problem when it is
    /// malformed.
    pub fn pose_covariance(
        &self,
    ) -> std::result::Result<Option<PoseCovariance>, PoseCovarianceError> {
        self.quality.pose_covariance()
    }

    /// The grade of the pose, `quality.grade`: `precise` for a file written before grades (it
    /// was served, so it passed the precise limits).
    pub fn grade(&self) -> &str {
        self.quality.grade.as_deref().unwrap_or("precise")
    }

    /// Why the pose is not precise, in one line, when it is not: `quality.reason`, and where the
    /// pose is the initializer's own (`quality.source` = `initializer`) the refinement's
    /// refusal behind it.
    pub fn grade_reason(&self) -> Option<String> {
        if self.grade() == "precise" {
            return None;
        }
        let reason = self.quality.reason.clone();
        let refused = (self.quality.rest.get("source").and_then(Value::as_str)
            == Some("initializer"))
        .then(|| {
            self.quality
                .rest
                .get("refinement_refused")
                .and_then(Value::as_str)
                .unwrap_or("no reason given")
        });
        match (reason, refused) {
            (Some(r), Some(x)) => Some(format!(
                "{r}; the initializer's pose, the refinement refused: {x}"
            )),
            (r, None) => r,
            (None, Some(x)) => Some(format!(
                "the initializer's pose, the refinement refused: {x}"
            )),
        }
    }

    /// The pose store's comparison score, `quality.score`, if the file has a numeric one.
    pub fn score(&self) -> Option<f64> {
        self.quality.score
    }

    /// Pretty JSON text with a trailing newline.
    pub fn to_json(&self) -> String {
        // Serialising plain data cannot fail; fall back to an empty object rather than panic.
        let mut s = serde_json::to_string_pretty(self).unwrap_or_else(|_| "{}".into());
        s.push('\n');
        s
    }
}

/// Why a pose file's `quality.covariance` is unusable; renders as `quality.covariance: …`.
#[derive(Debug, thiserror::Error)]
pub enum PoseCovarianceError {
    /// Not an object with `axes` and `matrix`.
    #[error("quality.covariance: {0}")]
    Malformed(#[source] serde_json::Error),
    /// Axes or entries the pose covariance cannot take.
    #[error("quality.covariance: {0}")]
    Entries(#[source] crate::geo::georef::CovarianceError),
}

/// [`PoseFile::pose_covariance`] of a `quality` block given as JSON (any value; one that is not
/// an object has no covariance).
pub fn pose_covariance_of(
    quality: &Value,
) -> std::result::Result<Option<PoseCovariance>, PoseCovarianceError> {
    PoseQuality::from_value(quality.clone()).pose_covariance()
}

/// The pose file's `quality` block (docs/interfaces.md, "Pose file"): the figures readers use,
/// typed, and every other key as written.
///
/// Each known figure is read on its own: one that is malformed (a hand-made file, an older or
/// other writer) reads as absent and stays, as written, in [`rest`](Self::rest), rather than
/// spoiling the rest of the file. A well-formed figure whose typed value would be written
/// differently (`1` for `1.0`, a `sigma` with further keys) is typed and its text is kept in
/// `rest` too, and written back as long as the typed value is unchanged; so a block read and
/// written again is the same JSON. A typed figure set to `None` is dropped with its text; a
/// malformed one in `rest` is kept.
///
/// It is written as one JSON object with its keys sorted (as a [`serde_json::Value`] writes
/// them), nested objects too, whatever the fields' order here.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PoseQuality {
    /// The pose store's comparison score (a localization writes its MI optimum's NMI).
    pub score: Option<f64>,
    /// The marginal σ per axis.
    pub sigma: Option<Sigma>,
    /// The marginal covariance: its axes, matrix and the rest of its object.
    pub covariance: Option<QualityCovariance>,
    /// The quality gate's verdict.
    pub accepted: Option<bool>,
    /// Why the gate refused (absent, or `null` kept in `rest`, when it accepted).
    pub reason: Option<String>,
    /// The grade: `precise`, `coarse` or `refused` (docs/pose.md "Grade"); absent in files
    /// written before grades, whose served poses were all precise.
    pub grade: Option<String>,
    /// Every other key, and the text of a known figure that is malformed or spelled otherwise
    /// than its typed value writes.
    pub rest: serde_json::Map<String, Value>,
}

/// `quality.covariance` of a pose file: `axes` and `matrix`, and every other key (`units`,
/// `sigma`, how it was estimated, …) as written.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct QualityCovariance {
    /// Axis names, in the matrix's order (x, y, z, yaw, then pitch, roll when estimated).
    pub axes: Vec<String>,
    /// The covariance, row-major (m, deg).
    pub matrix: Vec<Vec<f64>>,
    /// Every other key of the object.
    #[serde(flatten)]
    pub rest: serde_json::Map<String, Value>,
}

impl PoseQuality {
    /// The block of a JSON value: its known figures typed, the rest kept. A value that is not
    /// an object (`null`, a number, …) reads as an empty block.
    pub fn from_value(value: Value) -> Self {
        let Value::Object(mut rest) = value else {
            return PoseQuality::default();
        };
        PoseQuality {
            score: take_figure(&mut rest, "score"),
            sigma: take_figure(&mut rest, "sigma"),
            covariance: take_figure(&mut rest, "covariance"),
            accepted: take_figure(&mut rest, "accepted"),
            reason: take_figure(&mut rest, "reason"),
            grade: take_figure(&mut rest, "grade"),
            rest,
        }
    }

    /// The block as the JSON object the pose file holds.
    pub fn to_value(&self) -> Value {
        let mut m = self.rest.clone();
        put_figure(&mut m, "score", &self.score);
        put_figure(&mut m, "sigma", &self.sigma);
        put_figure(&mut m, "covariance", &self.covariance);
        put_figure(&mut m, "accepted", &self.accepted);
        put_figure(&mut m, "reason", &self.reason);
        put_figure(&mut m, "grade", &self.grade);
        Value::Object(m)
    }

    /// The pose's covariance (see [`PoseFile::pose_covariance`]).
    pub fn pose_covariance(
        &self,
    ) -> std::result::Result<Option<PoseCovariance>, PoseCovarianceError> {
        let (axes, matrix) = match (&self.covariance, self.rest.get("covariance")) {
            (Some(c), _) => (c.axes.clone(), c.matrix.clone()),
            (None, None) => return Ok(None),
            // A malformed one: read as before, for the same words (or the forms only this
            // reading takes, an `[axes, matrix]` array).
            (None, Some(raw)) => {
                #[derive(Deserialize)]
                struct Cov {
                    axes: Vec<String>,
                    matrix: Vec<Vec<f64>>,
                }
                let c = Cov::deserialize(raw).map_err(PoseCovarianceError::Malformed)?;
                (c.axes, c.matrix)
            }
        };
        PoseCovariance::from_axes(&axes, &matrix)
            .map(Some)
            .map_err(PoseCovarianceError::Entries)
    }
}

/// Figure `key` of `m` as a `T`, `None` when absent or malformed (then left in `m`). Taken out
/// of `m` when the `T` writes exactly what `m` holds; otherwise its text stays for
/// [`put_figure`].
fn take_figure<T: serde::de::DeserializeOwned + Serialize>(
    m: &mut serde_json::Map<String, Value>,
    key: &str,
) -> Option<T> {
    let raw = m.get(key)?;
    let t = T::deserialize(raw).ok()?;
    if serde_json::to_value(&t).ok().as_ref() == Some(raw) {
        m.remove(key);
    }
    Some(t)
}

/// Write figure `key` into `m` (which holds what [`take_figure`] left): its kept text while that
/// still reads as `v`, else `v` itself; for `None`, a kept text only if it is malformed.
fn put_figure<T: serde::de::DeserializeOwned + Serialize + PartialEq>(
    m: &mut serde_json::Map<String, Value>,
    key: &str,
    v: &Option<T>,
) {
    let kept = m.get(key).map(T::deserialize);
    match (v, kept) {
        (Some(t), Some(Ok(k))) if k == *t => {}
        (Some(t), _) => {
            m.insert(
                key.to_string(),
                serde_json::to_value(t).unwrap_or(Value::Null),
            );
        }
        (None, Some(Ok(_))) => {
            m.remove(key);
        }
        (None, _) => {}
    }
}

impl Serialize for PoseQuality {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        // Through a JSON value: its map writes the keys sorted, as the untyped block did.
        self.to_value().serialize(s)
    }
}

impl<'de> Deserialize<'de> for PoseQuality {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        Value::deserialize(d).map(PoseQuality::from_value)
    }
}

/// The minimal pose content any pose-like JSON must carry.
#[derive(Debug, Clone, Deserialize)]
struct MinimalPose {
    rotation_cam_from_map: [[f64; 3]; 3],
    translation_cam_from_map: [f64; 3],
    crs: Option<String>,
}

/// A pose read from a pose-like JSON (pose file, truth.json, hand-written initial pose).
#[derive(Debug, Clone)]
pub struct ReadPose {
    /// World→camera pose.
    pub pose: CamFromMap,
    /// The file's CRS, if it states one.
    pub crs: Option<Crs>,
    /// The one line to show when the file's rotation was re-orthonormalised (|RᵀR − I| between
    /// 1e-6 and 1e-4, [`crate::orthonormal`]), naming the file and field.
    pub note: Option<String>,
}

/// Parse pose-like JSON text. `origin` names the source in errors.
pub fn parse_pose(text: &str, origin: &Path) -> Result<ReadPose> {
    let m: MinimalPose = serde_json::from_str(text)
        .map_err(|e| Error::input(origin, format!("not a pose file: {e}")))?;
    let finite = m
        .rotation_cam_from_map
        .iter()
        .flatten()
        .all(|v| v.is_finite())
        && m.translation_cam_from_map.iter().all(|v| v.is_finite());
    if !finite {
        return Err(Error::input(
            origin,
            "rotation/translation contain non-finite values",
        ));
    }
    let r = nalgebra::Matrix3::from_row_slice(&m.rotation_cam_from_map.concat());
    let rot = crate::orthonormal::rotation_from_file(&r)
        .map_err(|e| Error::input(origin, format!("rotation_cam_from_map is {e}")))?;
    let crs = match m.crs {
        Some(s) => Some(
            s.parse::<Crs>()
                .map_err(|e| Error::input(origin, format!("crs: {e}")))?,
        ),
        None => None,
    };
    let t = m.translation_cam_from_map;
    Ok(ReadPose {
        pose: CamFromMap::new(rot.rotation, nalgebra::Vector3::new(t[0], t[1], t[2])),
        crs,
        note: rot.note(origin, "rotation_cam_from_map"),
    })
}

/// Format seconds since the Unix epoch (+ milliseconds) as `YYYY-MM-DDTHH:MM:SS[.mmm]Z`.
/// Pure: the caller supplies the clock reading. A time chrono cannot represent (beyond
/// ±262,000 years) is written as the epoch.
pub fn format_utc(unix_secs: i64, millis: Option<u32>) -> String {
    use chrono::{DateTime, SecondsFormat};
    let nanos = millis.map_or(0, |ms| ms.min(999) * 1_000_000);
    let t = DateTime::from_timestamp(unix_secs, nanos).unwrap_or_default();
    let precision = if millis.is_some() {
        SecondsFormat::Millis
    } else {
        SecondsFormat::Secs
    };
    t.to_rfc3339_opts(precision, true)
}

/// Seconds since the Unix epoch of an RFC 3339 timestamp (as `format_utc` writes them, or with
/// an offset); `None` if it is not one.
pub fn parse_utc(s: &str) -> Option<f64> {
    let t = chrono::DateTime::parse_from_rfc3339(s).ok()?;
    Some(t.timestamp() as f64 + f64::from(t.timestamp_subsec_nanos()) * 1e-9)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    #[test]
    fn round_trip_and_representations_agree() {
        let pose = CamFromMap::from_center_ypr(
            &Point3::new(500_100.5, 4_700_200.25, 207.0),
            2.0,
            0.02,
            -0.01,
        );
        let f = PoseFile::new(
            &pose,
            Crs::Epsg(32617),
            "t1",
            format_utc(1_795_262_400, None),
        );
        let text = f.to_json();
        let back: PoseFile = serde_json::from_str(&text).unwrap();
        assert_eq!(back, f);
        let p = parse_pose(&text, Path::new("p.json")).unwrap();
        assert_eq!(p.crs, Some(Crs::Epsg(32617)));
        assert!((p.pose.center() - pose.center()).norm() < 1e-6);
        // rvec and quaternion describe the same rotation as the matrix.
        let rv = nalgebra::Rotation3::new(nalgebra::Vector3::from(f.rvec_cam_from_map));
        assert!(crate::pose::rotation_angle_between(&rv, &pose.rotation) < 1e-12);
        let [x, y, z, w] = f.quaternion_map_from_cam_xyzw;
        let q = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z));
        assert!(
            crate::pose::rotation_angle_between(&q.to_rotation_matrix(), &pose.rotation.inverse())
                < 1e-12
        );
    }

    #[test]
    fn a_six_decimal_rotation_is_accepted_once_noted_and_1e_3_is_refused() {
        // KITTI-360's R_rect_00 as printed, a rotation to 1.7e-6.
        let text = r#"{"rotation_cam_from_map":[[0.999974,-0.007141,-0.000089],[0.007141,0.999969,-0.003247],[0.000112,0.003247,0.999995]],"translation_cam_from_map":[1,2,3]}"#;
        let p = parse_pose(text, Path::new("start.json")).unwrap();
        let note = p.note.unwrap();
        assert!(
            note.starts_with("start.json: rotation_cam_from_map re-orthonormalised (|RᵀR−I| = 1.")
                && !note.contains('\n'),
            "{note}"
        );
        let r = p.pose.rotation.matrix();
        assert!((r.transpose() * r - nalgebra::Matrix3::identity()).norm() < 1e-14);
        assert_eq!(p.pose.translation, nalgebra::Vector3::new(1.0, 2.0, 3.0));
        let off = text.replace("0.999974", "0.998974");
        let e = parse_pose(&off, Path::new("start.json"))
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("start.json: rotation_cam_from_map is not a rotation (|RᵀR−I| = 2.0")
                && !e.contains('\n'),
            "{e}"
        );
        // A pose file written by infraloc holds an exact rotation: nothing to say.
        let exact = PoseFile::new(&p.pose, Crs::Local, "", "t".into()).to_json();
        assert_eq!(parse_pose(&exact, Path::new("p.json")).unwrap().note, None);
    }

    #[test]
    fn rejects_non_rotation_and_garbage() {
        let bad = r#"{"rotation_cam_from_map":[[2,0,0],[0,1,0],[0,0,1]],"translation_cam_from_map":[0,0,0]}"#;
        let e = parse_pose(bad, Path::new("init.json"))
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("init.json: ") && e.contains("not a rotation"),
            "{e}"
        );
        let e = parse_pose("{", Path::new("x.json"))
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("x.json: not a pose file"), "{e}");
    }

    fn block(text: &str) -> PoseQuality {
        serde_json::from_str(text).unwrap()
    }

    fn written(q: &PoseQuality) -> String {
        serde_json::to_string(q).unwrap()
    }

    #[test]
    fn the_quality_block_writes_its_keys_sorted_as_the_untyped_one_did() {
        let v = serde_json::json!({
            "sigma": {"yaw": 0.1, "x": 0.01, "y": 0.02, "z": f64::INFINITY},
            "score": 0.5, "accepted": true, "reason": null, "mi": 0.3, "axes": [{"unit": "m", "axis": "x"}],
            "covariance": {"units": ["m"], "matrix": [[1e-4]], "axes": ["x"], "points": 12},
        });
        let q = PoseQuality::from_value(v.clone());
        assert_eq!(q.score, Some(0.5));
        assert_eq!(q.accepted, Some(true));
        assert_eq!(q.reason, None);
        assert_eq!(q.covariance.as_ref().unwrap().matrix, [[1e-4]]);
        // An infinite σ is written `null`: not a σ (as before), kept as written.
        assert_eq!(q.sigma, None);
        assert_eq!(q.to_value(), v);
        // Pretty and compact, the same text as the value's.
        assert_eq!(written(&q), serde_json::to_string(&v).unwrap());
        assert_eq!(
            serde_json::to_string_pretty(&q).unwrap(),
            serde_json::to_string_pretty(&v).unwrap()
        );
        // Built typed, written as the value of the same figures.
        let typed = PoseQuality {
            score: Some(0.25),
            sigma: Some(Sigma::by_axis(|_| Some(0.5))),
            accepted: Some(false),
            reason: Some("why".into()),
            ..Default::default()
        };
        assert_eq!(
            written(&typed),
            r#"{"accepted":false,"reason":"why","score":0.25,"sigma":{"pitch":0.5,"roll":0.5,"x":0.5,"y":0.5,"yaw":0.5,"z":0.5}}"#
        );
        assert_eq!(block(&written(&typed)), typed);
    }

    #[test]
    fn a_malformed_figure_reads_as_absent_and_is_kept_as_written() {
        let text = r#"{"covariance":{"axes":["x"]},"extra":{"a":[1,2],"b":1},"score":"high","sigma":{"x":"wide"}}"#;
        let q = block(text);
        assert_eq!((q.score, q.sigma, q.accepted), (None, None, None));
        assert!(q.covariance.is_none());
        assert_eq!(written(&q), text);
        // The covariance's error is the one an untyped block gave.
        let e = q.pose_covariance().unwrap_err().to_string();
        assert_eq!(e, "quality.covariance: missing field `matrix`");
        // A figure set over a malformed one replaces it; cleared, the malformed text stays.
        let mut q = q;
        q.score = Some(2.0);
        assert!(written(&q).contains(r#""score":2.0"#));
        q.score = None;
        assert_eq!(written(&q), text);
        // Not an object at all: an empty block, no figures.
        assert_eq!(
            PoseQuality::from_value(serde_json::json!(5)),
            PoseQuality::default()
        );
        assert!(pose_covariance_of(&Value::Null).unwrap().is_none());
    }

    #[test]
    fn a_figure_spelled_otherwise_is_typed_and_written_as_it_was() {
        let text = r#"{"accepted":true,"score":1,"sigma":{"note":"by hand","x":1,"y":0.02,"yaw":0.1,"z":0.03}}"#;
        let mut q = block(text);
        assert_eq!(q.score, Some(1.0));
        assert_eq!(q.sigma.unwrap().x, 1.0);
        assert_eq!(written(&q), text);
        // Changed, the new value is written; cleared, the figure goes.
        q.score = Some(0.5);
        q.sigma = None;
        assert_eq!(written(&q), r#"{"accepted":true,"score":0.5}"#);
    }

    #[test]
    fn utc_formatting() {
        assert_eq!(format_utc(0, None), "1970-01-01T00:00:00Z");
        assert_eq!(
            format_utc(1_795_262_400, Some(5)),
            "2026-11-21T12:00:00.005Z"
        );
        assert_eq!(format_utc(951_782_400, None), "2000-02-29T00:00:00Z");
        for d in [-700_000i64, -1, 0, 59, 11_016, 20_000, 2_000_000] {
            assert_eq!(
                parse_utc(&format_utc(d * 86_400, None)),
                Some((d * 86_400) as f64)
            );
        }
        let t = parse_utc("2026-11-21T12:00:00.005Z").unwrap();
        assert!((t - 1_795_262_400.005).abs() < 1e-6, "{t}");
        assert_eq!(
            parse_utc("2026-11-21T13:00:00+01:00"),
            Some(1_795_262_400.0)
        );
        assert_eq!(parse_utc("yesterday"), None);
    }
}
