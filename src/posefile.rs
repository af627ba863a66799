//! The `infraloc.pose.v1` document of the core ([`infraloc_core::posefile`]) and the reading of
//! pose files.

pub use infraloc_core::posefile::*;

use crate::error::{Error, Result};
use std::path::Path;

/// Read a pose-like JSON file.
pub fn read_pose(path: &Path) -> Result<ReadPose> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    Ok(parse_pose(&text, path)?)
}
