//! Reading a simulator `truth.json` back (docs/interfaces.md, "Scene directory"): the one parser every reader uses (the
//! scene reader, the report's errors against truth, the simulator's own tests). A malformed
//! control point is an error naming the file, never silently dropped.

use crate::error::{Error, Result};
use crate::map::Crs;
use crate::pose::CamFromMap;
use crate::sim::TruthPoint;
use std::path::Path;

/// The parts of a truth.json its readers use.
#[derive(Debug, Clone)]
pub struct Truth {
    /// The true pose.
    pub pose: CamFromMap,
    /// The file's CRS, if it states one.
    pub crs: Option<Crs>,
    /// The control points (none when the file has no `control_points`).
    pub control_points: Vec<TruthPoint>,
}

/// The control-point part of the document.
#[derive(serde::Deserialize)]
struct ControlPoints {
    #[serde(default)]
    control_points: Vec<TruthPoint>,
}

/// Parse truth.json text; `origin` names it in errors.
pub fn parse_truth(text: &str, origin: &Path) -> Result<Truth> {
    let pose = crate::posefile::parse_pose(text, origin)?;
    let cps: ControlPoints = serde_json::from_str(text)
        .map_err(|e| Error::input(origin, format!("control_points: {e}")))?;
    Ok(Truth {
        pose: pose.pose,
        crs: pose.crs,
        control_points: cps.control_points,
    })
}

/// Read and parse a truth.json file.
pub(crate) fn read_truth(path: &Path) -> Result<Truth> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    parse_truth(&text, path)
}
