//! `infraloc tile scans`: a tile from a vehicle's scans and their poses (docs/map.md, "From a
//! drive's scans to a tile"); the flags `tile build` shares mean what they mean there.

use super::{add_control_points, crs_flag, floats, report};
use crate::error::Result;
use crate::map::build::{build_from_scans, Area, GroundParams, ScansSpec};
use crate::map::cache::write_tile_with;
use crate::map::Crs;
use std::path::PathBuf;

/// Arguments of `tile scans`.
#[derive(Debug, clap::Args)]
pub struct ScansArgs {
    /// Scans in the scanner's frame: Velodyne .bin (KITTI), .pcd, .las, or directories of them;
    /// a scan's frame is the last run of digits in its file name.
    #[arg(required = true, value_name = "SCAN")]
    pub scans: Vec<PathBuf>,
    /// A pose per frame: KITTI-360 poses.txt (frame, then the vehicle's 3×4 row-major; needs
    /// --calib) or `frame x y z qx qy qz qw` lines (the scanner's own pose, map ← scanner).
    #[arg(long, value_name = "FILE")]
    pub poses: PathBuf,
    /// KITTI-360 calibration/ (or the dataset root): the Velodyne → vehicle transform from
    /// calib_cam_to_velo.txt and calib_cam_to_pose.txt.
    #[arg(long, value_name = "DIR")]
    pub calib: Option<PathBuf>,
    /// The projected CRS the poses' frame is placed in (the tile's CRS).
    #[arg(long, value_name = "EPSG:N")]
    pub crs: String,
    /// The poses' frame origin in --crs, added to every point: easting, northing, height.
    #[arg(long, value_name = "E,N,H", value_parser = floats::<3>, allow_hyphen_values = true,
          default_value = "0,0,0")]
    pub offset: [f64; 3],
    /// Tile box in --crs (default: the posed scans' extent).
    #[arg(long, value_name = "XMIN,YMIN,XMAX,YMAX", value_parser = floats::<4>,
          allow_hyphen_values = true, conflicts_with_all = ["center", "center_wgs84"])]
    pub bbox: Option<[f64; 4]>,
    /// Tile centre in --crs (a square of --size).
    #[arg(long, value_name = "X,Y", value_parser = floats::<2>, allow_hyphen_values = true,
          conflicts_with = "center_wgs84")]
    pub center: Option<[f64; 2]>,
    /// Tile centre as WGS84 latitude,longitude (a square of --size).
    #[arg(long, value_name = "LAT,LON", value_parser = floats::<2>, allow_hyphen_values = true)]
    pub center_wgs84: Option<[f64; 2]>,
    /// Side of the square tile around --center / --center-wgs84, metres.
    #[arg(long, value_name = "M", default_value_t = 200.0)]
    pub size: f64,
    /// LiDAR layer resolution, metres.
    #[arg(long, value_name = "M", default_value_t = 0.1)]
    pub res: f64,
    /// Satellite layer from this orthophoto (as `tile build`); without one the tile is LiDAR-only.
    #[arg(long, value_name = "FILE")]
    pub orthophoto: Option<PathBuf>,
    /// Satellite layer resolution, metres (default: --res).
    #[arg(long, value_name = "M")]
    pub satellite_res: Option<f64>,
    /// Ground filter cell, metres; a whole multiple of --res.
    #[arg(long, value_name = "M", default_value_t = 0.5)]
    pub ground_cell: f64,
    /// Ground filter window: wider than the widest object to remove, metres.
    #[arg(long, value_name = "M", default_value_t = 12.0)]
    pub ground_window: f64,
    /// Height above the filtered ground surface still counted as ground, metres.
    #[arg(long, value_name = "M", default_value_t = 0.2)]
    pub ground_tolerance: f64,
    /// Surveyed control points, CSV `id,x,y,z` in --crs.
    #[arg(long, value_name = "CSV")]
    pub control_points: Option<PathBuf>,
    /// Tile cache directory (created if missing).
    #[arg(long, value_name = "CACHE")]
    pub out: PathBuf,
    /// Tile id (the tile's directory name).
    #[arg(long, value_name = "TILE_ID")]
    pub id: String,
}

/// Run `tile scans`.
pub(super) fn run(a: &ScansArgs) -> Result<()> {
    let crs: Crs = a.crs.parse().map_err(crs_flag)?;
    let area = match (&a.bbox, &a.center, &a.center_wgs84) {
        (Some(b), _, _) => Some(Area::Box(*b)),
        (_, Some(c), _) => Some(Area::Center {
            xy: (c[0], c[1]),
            size: a.size,
        }),
        (_, _, Some(c)) => Some(Area::CenterWgs84 {
            lat: c[0],
            lon: c[1],
            size: a.size,
        }),
        _ => None,
    };
    let spec = ScansSpec {
        id: a.id.clone(),
        scans: a.scans.clone(),
        poses: a.poses.clone(),
        calib: a.calib.clone(),
        crs,
        offset: a.offset,
        area,
        res: a.res,
        ground: GroundParams {
            cell: a.ground_cell,
            window: a.ground_window,
            tolerance: a.ground_tolerance,
        },
        orthophoto: a.orthophoto.clone(),
        satellite_res: a.satellite_res,
    };
    let (mut tile, mut provenance) = build_from_scans(&spec)?;
    add_control_points(&mut tile, &mut provenance, a.control_points.as_deref())?;
    write_tile_with(&a.out, &tile, &provenance)?;
    report(&tile, &a.out);
    Ok(())
}
