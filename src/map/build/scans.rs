//! `infraloc tile scans`: a tile from a vehicle's own scans and a pose per scan (I/O shell;
//! docs/map.md, "From a drive's scans to a tile").
//!
//! Each scan (Velodyne `.bin`, PCD, LAS; `src/points_io.rs`) is put into the map frame by its
//! frame's pose: `X_map = offset + pose · calib · X_scan`, where `calib` is the scanner → vehicle
//! transform (KITTI-360: `T_cam00→pose · T_cam00→velo⁻¹` from `--calib`; identity for the plain
//! pose file, whose poses are the scanner's own). Then the ground filter and the rasteriser of
//! `tile build` ([`super`]), with the scans read three times instead of the points kept:
//! 1. (no box given) the posed points' extent;
//! 2. the lowest point of each ground cell, opened into the ground surface;
//! 3. each tile cell's ground points (at most [`MAX_PER_CELL`] of them, the first to arrive), whose
//!    medians are the cell's reflectivity and height.
//!
//! So memory is one scan plus the rasters (and at most `MAX_PER_CELL` × 12 bytes per cell with
//! ground), whatever the number of scans.

use super::{
    grid_params, lidar_only, open_surface, rasterize, read_grid, read_orthophoto, resolve_area,
    snapped_grid, warp_rgb, Area, GroundParams, Kept,
};
use crate::error::{Error, Result};
use crate::map::cache::Provenance;
use crate::map::{Crs, GeoGrid, Tile};
use crate::orthonormal::rotation_rows;
use nalgebra::{Isometry3, Point3, Quaternion, Translation3, UnitQuaternion, Vector3};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Ground points kept per tile cell: enough for a stable median, and a bound on memory however
/// many scans see the cell (a vehicle standing at a light sees the same cells for minutes).
pub(crate) const MAX_PER_CELL: u8 = 32;
/// Scan file extensions read from a directory.
const SCAN_EXTENSIONS: [&str; 3] = ["bin", "pcd", "las"];
/// Largest distance of a unit quaternion's norm from 1 (poses printed with few decimals).
const QUATERNION_NORM_TOL: f64 = 1e-3;
/// Frames listed by name in the warning about scans without a pose.
const LISTED_FRAMES: usize = 5;

/// What `tile scans` is asked for.
#[derive(Debug, Clone)]
pub(crate) struct ScansSpec {
    /// Tile id.
    pub id: String,
    /// Scan files, or directories of them (`.bin`, `.pcd`, `.las`); the frame is the last run of
    /// digits of the file name.
    pub scans: Vec<PathBuf>,
    /// The poses: KITTI-360 `poses.txt` (frame, 3×4 row-major) or `frame x y z qx qy qz qw`.
    pub poses: PathBuf,
    /// KITTI-360 `calibration/` (or the dataset root holding it): the Velodyne → vehicle transform.
    pub calib: Option<PathBuf>,
    /// The CRS the posed frame is placed in.
    pub crs: Crs,
    /// Added to every posed point: the frame's origin in `crs` (easting, northing, height).
    pub offset: [f64; 3],
    /// The tile's extent; `None`: the posed points' extent.
    pub area: Option<Area>,
    /// LiDAR layer resolution, metres.
    pub res: f64,
    /// Ground filter.
    pub ground: GroundParams,
    /// Orthophoto for the satellite layer.
    pub orthophoto: Option<PathBuf>,
    /// Satellite layer resolution, metres (default: `res`).
    pub satellite_res: Option<f64>,
}

/// The two pose file layouts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum PoseFormat {
    /// KITTI-360 `poses.txt`: frame, then the vehicle's 3×4 `[R | t]` row-major.
    Kitti360,
    /// `frame x y z qx qy qz qw`: the scanner's own pose (map ← scanner).
    Quaternion,
}

/// The poses of a pose file by frame.
pub(crate) type FramePoses = BTreeMap<u64, Isometry3<f64>>;

/// Parse a pose file: the pose of each frame (map ← vehicle for KITTI-360, map ← scanner for the
/// quaternion form), the layout, and the notes of re-orthonormalised rotations. Blank lines and
/// lines starting with `#` are skipped. `path` is for messages.
pub(crate) fn parse_poses(
    text: &str,
    path: &Path,
) -> Result<(FramePoses, PoseFormat, Vec<String>)> {
    let mut poses = BTreeMap::new();
    let mut format = None;
    let mut notes = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim_start_matches('\u{feff}').trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let at = |msg: String| Error::input(path, format!("line {}: {msg}", i + 1));
        let f: Vec<&str> = line.split_whitespace().collect();
        let this = match f.len() {
            13 => PoseFormat::Kitti360,
            8 => PoseFormat::Quaternion,
            n => {
                return Err(at(format!(
                    "{n} fields; expected 13 (KITTI-360: frame, then 3×4 row-major) or 8 (frame x y z qx qy qz qw)"
                )))
            }
        };
        if *format.get_or_insert(this) != this {
            return Err(at(format!(
                "{} fields, but the file's first pose has {}",
                f.len(),
                if this == PoseFormat::Kitti360 { 8 } else { 13 }
            )));
        }
        let frame: u64 = f[0]
            .parse()
            .map_err(|_| at(format!("frame {:?} is not a frame number", f[0])))?;
        let mut v = [0.0; 12];
        for (k, (s, out)) in f[1..].iter().zip(v.iter_mut()).enumerate() {
            *out = s
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| at(format!("field {} {s:?} is not a finite number", k + 2)))?;
        }
        let pose = match this {
            PoseFormat::Kitti360 => {
                let rows = [v[0], v[1], v[2], v[4], v[5], v[6], v[8], v[9], v[10]];
                let field = format!("line {} (frame {frame}) rotation", i + 1);
                let r =
                    rotation_rows(&rows, &field).map_err(|e| Error::input(path, e.to_string()))?;
                notes.extend(r.note(path, &field));
                Isometry3::from_parts(Translation3::new(v[3], v[7], v[11]), r.rotation.into())
            }
            PoseFormat::Quaternion => {
                let q = Quaternion::new(v[6], v[3], v[4], v[5]);
                if (q.norm() - 1.0).abs() > QUATERNION_NORM_TOL {
                    return Err(at(format!(
                        "quaternion (qx, qy, qz, qw) = ({}, {}, {}, {}) has norm {:.6}, not 1",
                        v[3],
                        v[4],
                        v[5],
                        v[6],
                        q.norm()
                    )));
                }
                Isometry3::from_parts(
                    Translation3::new(v[0], v[1], v[2]),
                    UnitQuaternion::from_quaternion(q),
                )
            }
        };
        if poses.insert(frame, pose).is_some() {
            return Err(at(format!("frame {frame} is given twice")));
        }
    }
    let format = format.ok_or_else(|| Error::input(path, "no poses"))?;
    Ok((poses, format, notes))
}

/// The frame number of a scan file: the last run of digits in its name (`0000000250.bin` → 250,
/// `scan_042.pcd` → 42).
pub(crate) fn scan_frame(path: &Path) -> Option<u64> {
    let stem = path.file_stem()?.to_str()?;
    let end = stem.rfind(|c: char| c.is_ascii_digit())? + 1;
    let start = stem[..end]
        .rfind(|c: char| !c.is_ascii_digit())
        .map_or(0, |i| i + 1);
    stem[start..end].parse().ok()
}

/// The scan files of the inputs: files as given, directories' scan files by name.
fn scan_files(inputs: &[PathBuf]) -> Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    for p in inputs {
        if !p.is_dir() {
            out.push(p.clone());
            continue;
        }
        let mut found: Vec<PathBuf> = std::fs::read_dir(p)
            .map_err(|e| Error::io(p, e))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|f| {
                f.is_file()
                    && f.extension()
                        .and_then(|e| e.to_str())
                        .is_some_and(|e| SCAN_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
            })
            .collect();
        if found.is_empty() {
            return Err(Error::input(
                p,
                "no scan files (.bin, .pcd or .las) in the directory",
            ));
        }
        found.sort();
        out.append(&mut found);
    }
    Ok(out)
}

/// The Velodyne → vehicle transform of a KITTI-360 `calibration/` directory (or of the dataset
/// root holding one).
fn kitti360_calib(dir: &Path) -> Result<(Isometry3<f64>, Vec<String>)> {
    let dir = if dir.join("calibration").is_dir() {
        dir.join("calibration")
    } else {
        dir.to_path_buf()
    };
    let (velo, pose) = (
        dir.join("calib_cam_to_velo.txt"),
        dir.join("calib_cam_to_pose.txt"),
    );
    let read = |p: &Path| std::fs::read_to_string(p).map_err(|e| Error::io(p, e));
    let (tv, tp) = (read(&velo)?, read(&pose)?);
    let src = |path, text| crate::camera::kitti_rigs::Source { path, text };
    let (r, t, notes) =
        crate::camera::kitti_rigs::kitti360_velo_to_pose(src(&velo, &tv), src(&pose, &tp))?;
    Ok((
        Isometry3::from_parts(Translation3::from(t), r.into()),
        notes,
    ))
}

/// The scans with a pose, each with its scanner → map transform (offset not included).
struct Posed {
    scans: Vec<(PathBuf, Isometry3<f64>)>,
    offset: Vector3<f64>,
}

impl Posed {
    /// Each posed point in the map frame: `f(x, y, z, reflectivity)`, one scan in memory at a time.
    fn each_point(&self, mut f: impl FnMut(f64, f64, f64, u8)) -> Result<()> {
        for (path, pose) in &self.scans {
            for p in crate::points_io::read_points(path)? {
                let m = pose * Point3::new(p.x, p.y, p.z) + self.offset;
                f(m.x, m.y, m.z, p.reflectivity);
            }
        }
        Ok(())
    }
}

/// The posed scans of `spec`, with the provenance line of the poses; scans without a pose are
/// named in one warning.
fn posed_scans(spec: &ScansSpec) -> Result<(Posed, String)> {
    let text = std::fs::read_to_string(&spec.poses).map_err(|e| Error::io(&spec.poses, e))?;
    let (poses, format, mut notes) = parse_poses(&text, &spec.poses)?;
    let (calib, what) = match (format, &spec.calib) {
        (PoseFormat::Kitti360, Some(dir)) => {
            let (c, mut n) = kitti360_calib(dir)?;
            notes.append(&mut n);
            (c, format!("KITTI-360 vehicle poses, Velodyne → vehicle from {}", dir.display()))
        }
        (PoseFormat::Kitti360, None) => {
            return Err(Error::input(
                &spec.poses,
                "KITTI-360 vehicle poses (3×4) need --calib DIR (calibration/ with \
                 calib_cam_to_pose.txt and calib_cam_to_velo.txt): the scans are in the Velodyne frame",
            ))
        }
        (PoseFormat::Quaternion, Some(_)) => {
            return Err(Error::input(
                &spec.poses,
                "--calib is for KITTI-360 poses.txt; `frame x y z qx qy qz qw` poses are the scanner's own",
            ))
        }
        (PoseFormat::Quaternion, None) => (Isometry3::identity(), "scanner poses".to_string()),
    };
    for n in &notes {
        crate::cli::note(n);
    }
    let files = scan_files(&spec.scans)?;
    let mut scans = Vec::new();
    let mut unposed = Vec::new();
    for f in files {
        let frame = scan_frame(&f).ok_or_else(|| {
            Error::input(
                &f,
                "no frame number in the file name (its last run of digits)",
            )
        })?;
        match poses.get(&frame) {
            Some(p) => scans.push((f, p * calib)),
            None => unposed.push(frame),
        }
    }
    if scans.is_empty() {
        return Err(Error::input(
            &spec.poses,
            format!(
                "none of the {} scans has a pose here (frames {})",
                unposed.len(),
                frames_list(&unposed)
            ),
        ));
    }
    if !unposed.is_empty() {
        eprintln!(
            "infraloc: warning: {}: {} of {} scans have no pose and are left out (frames {})",
            spec.poses.display(),
            unposed.len(),
            unposed.len() + scans.len(),
            frames_list(&unposed)
        );
    }
    let [e, n, h] = spec.offset;
    let line = format!(
        "scans: {} posed by {} ({what}), offset ({e}, {n}, {h}) into {}; {} without a pose left out",
        scans.len(),
        spec.poses.display(),
        spec.crs,
        unposed.len()
    );
    let offset = Vector3::from(spec.offset);
    Ok((Posed { scans, offset }, line))
}

/// The first frames of a list, for messages.
fn frames_list(frames: &[u64]) -> String {
    let mut s = frames
        .iter()
        .take(LISTED_FRAMES)
        .map(u64::to_string)
        .collect::<Vec<_>>()
        .join(", ");
    if frames.len() > LISTED_FRAMES {
        s.push_str(", …");
    }
    s
}

/// The read-grid cell of (x, y), if inside.
fn cell_of(g: &GeoGrid, x: f64, y: f64) -> Option<(usize, usize)> {
    let col = ((x - g.x0) / g.res).floor();
    let row = ((g.y0 - y) / g.res).floor();
    (col >= 0.0 && row >= 0.0 && (col as usize) < g.width && (row as usize) < g.height)
        .then_some((row as usize, col as usize))
}

/// Build the tile. Returns it and its provenance.
pub(crate) fn build_from_scans(spec: &ScansSpec) -> Result<(Tile, Provenance)> {
    let ratio = grid_params(spec.res, spec.ground)?;
    let (res, gp) = (spec.res, spec.ground);
    crate::geo::check_crs(spec.crs).map_err(|source| crate::map::MapError::Flag {
        flag: "--crs",
        source,
    })?;
    if !spec.offset.iter().all(|v| v.is_finite()) {
        return Err(Error::arg(
            "--offset",
            format!("{:?}", spec.offset),
            "must be finite",
        ));
    }
    let (posed, poses_line) = posed_scans(spec)?;
    // The orthophoto is read before the scans so that a bad one fails fast.
    let ortho = match &spec.orthophoto {
        Some(p) => Some((p.as_path(), read_orthophoto(p, spec.crs)?)),
        None => None,
    };
    let bx = match spec.area {
        Some(a) => resolve_area(a, spec.crs, &[])?,
        None => {
            let mut b = [
                f64::INFINITY,
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::NEG_INFINITY,
            ];
            posed.each_point(|x, y, _, _| {
                b = [b[0].min(x), b[1].min(y), b[2].max(x), b[3].max(y)];
            })?;
            b
        }
    };
    let tile_grid = snapped_grid(spec.crs, &bx, res, "tile")?;
    let margin_cells = (gp.window / 2.0 / gp.cell).ceil() as usize * ratio;
    let (read, _) = read_grid(&tile_grid, margin_cells)?;
    let sat_grid = match spec.satellite_res {
        Some(r) if !(r > 0.0) || !r.is_finite() => {
            return Err(crate::map::MapError::NotPositive {
                flag: "--satellite-res",
                value: r,
            }
            .into())
        }
        Some(r) => snapped_grid(spec.crs, &bx, r, "satellite")?,
        None => tile_grid,
    };
    // Pass 1: the lowest point of each ground cell, opened into the ground surface.
    let (gw, gh) = (read.width.div_ceil(ratio), read.height.div_ceil(ratio));
    let mut low = vec![f32::INFINITY; gw * gh];
    let mut in_box = 0u64;
    posed.each_point(|x, y, z, _| {
        if let Some((row, col)) = cell_of(&read, x, y) {
            let g = (row / ratio) * gw + col / ratio;
            low[g] = low[g].min(z as f32);
            in_box += 1;
        }
    })?;
    let surface = open_surface(&low, gw, gh, gp);
    drop(low);
    // Pass 2: the tile's ground points, at most MAX_PER_CELL a cell.
    let mut count = vec![0u8; tile_grid.len()];
    let mut kept: Vec<Kept> = Vec::new();
    posed.each_point(|x, y, z, refl| {
        let Some((row, col)) = cell_of(&read, x, y) else {
            return;
        };
        let (Some(r), Some(c)) = (row.checked_sub(margin_cells), col.checked_sub(margin_cells))
        else {
            return;
        };
        if r >= tile_grid.height || c >= tile_grid.width {
            return;
        }
        let z = z as f32;
        let s = surface[(row / ratio) * gw + col / ratio];
        let n = &mut count[r * tile_grid.width + c];
        if f64::from(z) <= f64::from(s) + gp.tolerance && *n < MAX_PER_CELL {
            *n += 1;
            kept.push(Kept {
                cell: (row * read.width + col) as u32,
                z,
                intensity: u16::from(refl),
                src: 0,
            });
        }
    })?;
    drop(count);
    // One unclassified input of 8-bit reflectivity (the point readers scale each scan to 0–255).
    let (refl, height, n_ground) = rasterize(
        &mut kept,
        &[false],
        &[255.0],
        Some(&surface),
        &read,
        &tile_grid,
        margin_cells,
        ratio,
        gp.tolerance,
    );
    drop(kept);
    let names = spec.poses.display().to_string();
    if n_ground == 0 {
        let (a, b, c, d) = tile_grid.bounds();
        return Err(Error::input(
            &spec.poses,
            format!(
                "no ground points in the box x {a}..{c}, y {b}..{d} ({}; {in_box} posed points within the box and its margin)",
                spec.crs
            ),
        ));
    }
    let mut sources = vec![poses_line];
    let satellite = match ortho {
        Some((path, img)) => {
            sources.push(format!("satellite: {} warped bilinearly", path.display()));
            Some(warp_rgb(&img, path, &sat_grid)?)
        }
        None => {
            lidar_only(&names, "scans carry no colour", &mut sources);
            None
        }
    };
    let note = format!(
        "tile scans: {res} m grid; ground cell {} m, window {} m, tolerance {} m; reflectivity = \
         median ground reflectivity, height = median ground height of at most {MAX_PER_CELL} \
         ground points a cell ({n_ground} cells)",
        gp.cell, gp.window, gp.tolerance
    );
    let tile = Tile {
        id: spec.id.clone(),
        satellite,
        reflectivity: refl,
        height,
        control_points: Vec::new(),
    };
    let provenance = Provenance {
        sources,
        note: Some(note),
        ..Default::default()
    };
    Ok((tile, provenance))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_from_file_names() {
        let f = |s: &str| scan_frame(Path::new(s));
        assert_eq!(f("velodyne/0000000250.bin"), Some(250));
        assert_eq!(f("scan_042.pcd"), Some(42));
        assert_eq!(f("run2/frame17_lidar.las"), Some(17));
        assert_eq!(f("ground.pcd"), None);
    }

    #[test]
    fn both_pose_layouts_and_their_refusals() {
        let p = Path::new("poses.txt");
        let k = "# comment\n250 0 -1 0 10  1 0 0 20  0 0 1 30\n\n251 1 0 0 1 0 1 0 2 0 0 1 3\n";
        let (poses, fmt, notes) = parse_poses(k, p).unwrap();
        assert_eq!(fmt, PoseFormat::Kitti360);
        assert!(notes.is_empty());
        let m = poses[&250] * Point3::new(1.0, 2.0, 3.0);
        // R = [[0,-1,0],[1,0,0],[0,0,1]]: (1,2,3) → (-2, 1, 3), then + (10, 20, 30).
        assert!((m - Point3::new(8.0, 21.0, 33.0)).norm() < 1e-12, "{m}");
        // A quarter turn about z as a quaternion (qw = qz = √½).
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let q = format!("7 10 20 30 0 0 {h} {h}\n");
        let (poses, fmt, _) = parse_poses(&q, p).unwrap();
        assert_eq!(fmt, PoseFormat::Quaternion);
        let m = poses[&7] * Point3::new(1.0, 2.0, 3.0);
        assert!((m - Point3::new(8.0, 21.0, 33.0)).norm() < 1e-12, "{m}");
        for (text, want) in [
            ("1 2 3\n", "line 1: 3 fields"),
            (
                "7 0 0 0 0 0 0 1\n8 1 0 0 0 1 0 0 0 0 1 0 0\n",
                "line 2: 13 fields, but",
            ),
            ("x 0 0 0 0 0 0 1\n", "frame \"x\""),
            (
                "7 0 0 0 0 0 0 1\n7 0 0 0 0 0 0 1\n",
                "line 2: frame 7 is given twice",
            ),
            ("7 0 0 0 0 0 0 2\n", "norm 2.000000"),
            ("7 0 0 nan 0 0 0 1\n", "field 4 \"nan\""),
            ("1 2 0 0 0 0 2 0 0 0 0 2 0\n", "rotation"),
            ("# nothing\n", "no poses"),
        ] {
            let e = parse_poses(text, p).unwrap_err().to_string();
            assert!(e.contains("poses.txt") && e.contains(want), "{text:?}: {e}");
            assert_eq!(e.lines().count(), 1, "{e}");
        }
    }
}
