//! `infraloc project --camera CAM [--pose POSE.json] --points CSV` (docs/interfaces.md, "Command line and exit codes").
//!
//! Reads `x,y,z` rows (an optional header line is detected; columns after the third are ignored),
//! in the camera frame, or in the map frame when a pose is given (`X_c = R·X_w + t`), and prints
//! one `u,v` line per input row. A row the model cannot map one-to-one (behind the mirror, past the
//! distortion fold, zero or non-finite) prints `,`. Pixels off the sensor are still printed: the
//! command reports the model, not visibility. Values are printed as the shortest decimal that
//! reads back to the same f64.

use crate::camera::{load_camera, CameraModel};
use crate::error::{Error, Result};
use crate::posefile::read_pose;
use nalgebra::Vector3;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Arguments of `project`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Intrinsics file (OpenCV FileStorage YAML/XML, Kalibr camchain `FILE[#camN]`, KITTI-360 MEI
    /// YAML or TOML).
    #[arg(long)]
    pub camera: PathBuf,
    /// Pose file with `rotation_cam_from_map` and `translation_cam_from_map` (pose JSON or a
    /// simulator truth.json); the points are then in the map frame.
    #[arg(long)]
    pub pose: Option<PathBuf>,
    /// CSV of points `x,y,z` (header optional).
    #[arg(long)]
    pub points: PathBuf,
}

/// Run `project`.
pub(super) fn run(a: Args) -> Result<()> {
    let cam = load_camera(&a.camera)?;
    // Pose file (docs/interfaces.md, "Pose file") or a simulator truth.json: only the rotation and translation are used.
    let pose = a.pose.as_deref().map(read_pose).transpose()?.map(|p| {
        if let Some(n) = &p.note {
            super::note(n);
        }
        p.pose
    });
    let text = std::fs::read_to_string(&a.points).map_err(|e| Error::io(&a.points, e))?;
    let points = parse_points(&text, &a.points)?;
    let mut out = String::with_capacity(points.len() * 40);
    for p in &points {
        let pc = match &pose {
            Some(t) => t.rotation * p + t.translation,
            None => *p,
        };
        out.push_str(&format_uv(&cam, &pc));
        out.push('\n');
    }
    let stdout = std::io::stdout();
    let mut lock = stdout.lock();
    lock.write_all(out.as_bytes())
        .and_then(|_| lock.flush())
        .map_err(|e| Error::io("<stdout>", e))
}

/// One output line (without newline): `u,v`, or `,` when the point has no image.
pub(crate) fn format_uv(cam: &dyn CameraModel, p_cam: &Vector3<f64>) -> String {
    match cam.project(p_cam) {
        // `{}` on f64 is the shortest representation that parses back to the same value.
        Ok(px) => format!("{},{}", px.x, px.y),
        Err(_) => ",".to_string(),
    }
}

/// Parse CSV rows `x,y,z[,…]`. The first non-blank line is a header if any of its first three
/// fields is not a number; blank lines are skipped. Errors name the file and the 1-based line.
pub(crate) fn parse_points(text: &str, origin: &Path) -> Result<Vec<Vector3<f64>>> {
    Ok(parse_rows(text, origin, ["x", "y", "z"])?
        .into_iter()
        .map(Vector3::from)
        .collect())
}

/// Parse CSV rows of `N` leading numbers named `names` (further columns ignored). The first
/// non-blank line is a header if any of its first `N` fields is not a number (`nan` and `inf`
/// are numbers); blank lines are skipped. Errors name the file and the 1-based line.
pub(crate) fn parse_rows<const N: usize>(
    text: &str,
    origin: &Path,
    names: [&str; N],
) -> Result<Vec<[f64; N]>> {
    let mut rows = Vec::new();
    let mut first = true;
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() {
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        let nums: Vec<Option<f64>> = fields.iter().map(|f| f.parse::<f64>().ok()).collect();
        let is_first = std::mem::replace(&mut first, false);
        if is_first && fields.len() >= N && nums[..N].iter().any(Option::is_none) {
            continue; // header
        }
        if fields.len() < N {
            return Err(Error::input(
                origin,
                format!(
                    "line {}: expected {}, found {} field(s)",
                    i + 1,
                    names.join(","),
                    fields.len()
                ),
            ));
        }
        match nums[..N].iter().position(Option::is_none) {
            None => rows.push(std::array::from_fn(|k| nums[k].unwrap_or_default())),
            Some(k) => {
                return Err(Error::input(
                    origin,
                    format!("line {}: {} is not a number in {line:?}", i + 1, names[k]),
                ));
            }
        }
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_detected_and_errors_name_line() {
        let p = Path::new("pts.csv");
        let v = parse_points("x,y,z\n1,2,3\n\n4, 5 ,6,99\n", p).unwrap();
        assert_eq!(
            v,
            vec![Vector3::new(1.0, 2.0, 3.0), Vector3::new(4.0, 5.0, 6.0)]
        );
        let v = parse_points("1,2,3\n", p).unwrap();
        assert_eq!(v.len(), 1);
        let e = parse_points("x,y,z\n1,2,3\n1,a,3\n", p)
            .unwrap_err()
            .to_string();
        assert_eq!(e, "pts.csv: line 3: y is not a number in \"1,a,3\"");
        let e = parse_points("1,2\n", p).unwrap_err().to_string();
        assert_eq!(e, "pts.csv: line 1: expected x,y,z, found 2 field(s)");
        // A header is only allowed first.
        assert!(parse_points("1,2,3\nx,y,z\n", p).is_err());
    }
}
