//! `infraloc kitti import`: a KITTI object-benchmark frame's calibration as infraloc inputs.
//!
//! A KITTI `calib/NNNNNN.txt` holds the rectified pinholes `P0..P3` and the Velodyne → camera
//! extrinsic but no image size, so it is not an intrinsics file by itself (docs/interfaces.md, "Camera intrinsics files"). This
//! command reads it with the frame's image (for the size) and writes
//! - the camera as OpenCV FileStorage YAML (Mei with ξ = 0 and no distortion: exactly the pinhole),
//! - the camera's pose with the **Velodyne frame as the map frame** (`"crs": "LOCAL"`: x forward,
//!   y left, z up, metres) as an `infraloc.pose.v1` JSON that `refine --init`, `plot mi-surface
//!   --pose` and `project --pose` read,
//! - optionally a start perturbed from it (`--perturb x=…,y=…,z=…,yaw=…`, the search's own move:
//!   centre shifted in the Velodyne frame, yaw about its up axis through the camera centre).
//!
//! So a LiDAR–camera rig's extrinsic can be checked (or re-estimated) with `refine --points
//! velodyne/NNNNNN.bin`, and the official calibration is the ground truth (docs/refine.md "Real
//! data").

use crate::camera::import::{parse_kitti_calib, to_opencv_yaml};
use crate::error::{Error, Result};
use crate::map::Crs;
use crate::pose::CamFromMap;
use crate::posefile::{format_utc, PoseFile};
use std::path::{Path, PathBuf};

/// `kitti` subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum Command {
    /// Camera YAML and Velodyne-frame pose JSON from a KITTI calibration file and its image.
    Import(ImportArgs),
}

/// Arguments of `kitti import`.
#[derive(Debug, clap::Args)]
pub struct ImportArgs {
    /// KITTI object-benchmark calibration (`calib/NNNNNN.txt`: P0..P3, R0_rect, Tr_velo_to_cam).
    #[arg(long)]
    pub calib: PathBuf,
    /// The frame's image (`image_2/NNNNNN.png` for P2); only its size is read.
    #[arg(long)]
    pub image: PathBuf,
    /// Which rectified camera: P0, P1 (gray), P2 (left colour, default), P3.
    #[arg(long, default_value = "P2")]
    pub camera: String,
    /// Write the camera here (OpenCV FileStorage YAML, docs/interfaces.md, "Camera intrinsics files").
    #[arg(long)]
    pub camera_out: PathBuf,
    /// Write the calibration's camera pose here (Velodyne frame as the map, crs LOCAL).
    #[arg(long)]
    pub pose_out: PathBuf,
    /// Offsets for a perturbed start: x=M,y=M,z=M,yaw=DEG[,pitch=DEG,roll=DEG] (missing = 0).
    #[arg(long, requires = "start_out")]
    pub perturb: Option<String>,
    /// Write the perturbed start here (with --perturb).
    #[arg(long, requires = "perturb")]
    pub start_out: Option<PathBuf>,
}

/// Run a `kitti` subcommand.
pub(super) fn run(c: Command) -> Result<()> {
    match c {
        Command::Import(a) => import(a),
    }
}

/// Parse `x=…,y=…,z=…,yaw=…[,pitch=…,roll=…]` into the search's offsets (m, m, m, °, °, °).
pub(crate) fn parse_perturbation(s: &str) -> Result<[f64; 6]> {
    const KEYS: [&str; 6] = ["x", "y", "z", "yaw", "pitch", "roll"];
    let bad = |m: String| Error::Invalid(format!("--perturb {s:?}: {m}"));
    let mut o = [0.0; 6];
    let mut seen = [false; 6];
    for part in s.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let (k, v) = part
            .split_once('=')
            .ok_or_else(|| bad(format!("{part:?} is not KEY=VALUE")))?;
        let i = KEYS
            .iter()
            .position(|n| *n == k.trim())
            .ok_or_else(|| bad(format!("unknown axis {k:?} (x, y, z, yaw, pitch, roll)")))?;
        if seen[i] {
            return Err(bad(format!("{k} given twice")));
        }
        seen[i] = true;
        o[i] = v
            .trim()
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| bad(format!("{k}: {v:?} is not a finite number")))?;
    }
    Ok(o)
}

fn pose_json(pose: &CamFromMap, cam_json: serde_json::Value, stage: serde_json::Value) -> String {
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs() as i64)
        .unwrap_or(0);
    let mut pf = PoseFile::new(pose, Crs::Local, "", format_utc(now, None));
    pf.intrinsics = cam_json;
    pf.stages = vec![stage];
    pf.to_json()
}

fn import(a: ImportArgs) -> Result<()> {
    // Everything is parsed and checked before anything is written.
    let perturb = a.perturb.as_deref().map(parse_perturbation).transpose()?;
    let text = std::fs::read_to_string(&a.calib).map_err(|e| Error::io(&a.calib, e))?;
    let calib = parse_kitti_calib(&text, &a.calib)?;
    let (w, h) = image::image_dimensions(&a.image)
        .map_err(|e| Error::input(&a.image, format!("cannot read image size: {e}")))?;
    let cam = calib
        .camera(&a.camera, w, h)
        .map_err(|m| Error::input(&a.calib, m))?;
    let (r, t) = calib
        .cam_from_velo(&a.camera)
        .map_err(|m| Error::input(&a.calib, m))?;
    let pose = CamFromMap::from_rows(r, t);
    let cam_json = serde_json::to_value(&cam).unwrap_or_default();
    let source = |p: &Path| p.display().to_string();
    let stage = serde_json::json!({
        "name": "kitti-calibration",
        "calib": source(&a.calib),
        "camera": a.camera,
        "map_frame": "velodyne",
    });
    crate::persist::write_atomic(&a.camera_out, to_opencv_yaml(&cam).as_bytes())?;
    crate::persist::write_atomic(
        &a.pose_out,
        pose_json(&pose, cam_json.clone(), stage.clone()).as_bytes(),
    )?;
    let c = pose.center();
    let (yaw, pitch, roll) = pose.yaw_pitch_roll();
    println!(
        "kitti: {} {w}×{h}, f = {:.3} px; camera centre ({:+.4}, {:+.4}, {:+.4}) m in the Velodyne \
         frame, yaw {:.3}°, pitch {:.3}°, roll {:.3}°; wrote {} and {}",
        a.camera,
        match &cam {
            crate::camera::Camera::Mei(m) => m.fx,
            crate::camera::Camera::Equidistant(e) => e.fx,
        },
        c.x,
        c.y,
        c.z,
        yaw.to_degrees(),
        pitch.to_degrees(),
        roll.to_degrees(),
        a.camera_out.display(),
        a.pose_out.display()
    );
    if let (Some(o), Some(path)) = (perturb, &a.start_out) {
        let start = crate::localize::mi::space::pose_at(&pose, &o);
        let mut stage = stage;
        stage["perturbation"] = serde_json::json!({
            "x_m": o[0], "y_m": o[1], "z_m": o[2], "yaw_deg": o[3], "pitch_deg": o[4], "roll_deg": o[5],
        });
        crate::persist::write_atomic(path, pose_json(&start, cam_json, stage).as_bytes())?;
        println!(
            "kitti: start perturbed by ({:+.3}, {:+.3}, {:+.3}) m, yaw {:+.3}°, pitch {:+.3}°, roll \
             {:+.3}°: wrote {}",
            o[0],
            o[1],
            o[2],
            o[3],
            o[4],
            o[5],
            path.display()
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn perturbation_spec() {
        assert_eq!(
            parse_perturbation("x=0.1, yaw=-1.5,z=0.02").unwrap(),
            [0.1, 0.0, 0.02, -1.5, 0.0, 0.0]
        );
        assert_eq!(parse_perturbation("").unwrap(), [0.0; 6]);
        for (bad, what) in [
            ("x=1,x=2", "given twice"),
            ("q=1", "unknown axis"),
            ("x=nan", "not a finite number"),
            ("x", "not KEY=VALUE"),
        ] {
            let e = parse_perturbation(bad).unwrap_err().to_string();
            assert!(e.starts_with("--perturb") && e.contains(what), "{e}");
        }
    }
}
