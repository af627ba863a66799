//! `infraloc georef`: pixels → map points through the served pose (docs/georef.md).
//!
//! A shell over [`crate::geo::georef`]: it reads the pose file, the camera and the pose's tile,
//! reads `u,v` rows (CSV, header optional, from `--pixels` or stdin) and prints one record per
//! row, in order, as CSV or JSON. A pixel without a map point has its status and empty fields;
//! only unreadable inputs fail the command.

use crate::camera::{load_camera, Camera};
use crate::config::Config;
use crate::error::{Error, Result};
use crate::geo::georef::{
    self, Ellipse, HeightSurface, MapPoint, Params, PoseWithCovariance, Status, Surface,
};
use crate::map::cache::load_tile;
use crate::map::Crs;
use crate::posefile::{parse_pose, pose_covariance_of};
use serde_json::{json, Value};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

/// Output format of `georef`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// One CSV line per pixel, with a header.
    Csv,
    /// One JSON document: the pose used and a record per pixel.
    Json,
}

/// Arguments of `georef`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Configuration file: its `[output] pose`, camera and `[map] tiles` are used for whatever
    /// --pose, --camera and --tiles do not give (not read when all three are given).
    #[arg(long, default_value = super::DEFAULT_CONFIG)]
    pub config: PathBuf,
    /// Pose file (default: the config's `[output] pose`, the served pose).
    #[arg(long)]
    pub pose: Option<PathBuf>,
    /// Intrinsics file (default: the config's camera).
    #[arg(long)]
    pub camera: Option<PathBuf>,
    /// Tile cache (default: the config's `[map] tiles`); the tile is the pose file's `tile_id`.
    /// A tile directory itself is accepted too.
    #[arg(long)]
    pub tiles: Option<PathBuf>,
    /// CSV of pixels `u,v` (header optional, further columns ignored); `-` or absent: stdin.
    #[arg(long)]
    pub pixels: Option<PathBuf>,
    /// Output format.
    #[arg(long, value_enum, default_value = "csv")]
    pub format: Format,
    /// Intersect with the horizontal plane at this height (map frame, m) instead of the tile's
    /// height layer (no tile is read).
    #[arg(long)]
    pub plane: Option<f64>,
    /// Pixel noise σ (px) added to each point's covariance (a detector's box centre).
    #[arg(long, default_value_t = 0.0)]
    pub sigma_px: f64,
    /// Largest angle of a ray from nadir, degrees; beyond it a pixel is `grazing`.
    #[arg(long, default_value_t = georef::DEFAULT_MAX_OFF_NADIR_DEG)]
    pub max_off_nadir: f64,
}

/// The pose `georef` works through and what names it.
pub(crate) struct UsedPose {
    /// Pose and covariance.
    pub(crate) pose: PoseWithCovariance,
    /// The file's `timestamp_utc`, `tile_id`, `crs` and `quality.sigma` (null where absent).
    pub(crate) describe: Value,
    /// The tile the pose was computed against, if the file names it.
    pub(crate) tile_id: Option<String>,
    /// The pose's CRS, if stated.
    pub(crate) crs: Option<Crs>,
}

/// Read a pose-like JSON (a pose file; a hand-written pose or a truth.json count as exact).
/// A pose file whose `status` is not `ok` is refused.
pub(crate) fn read_used_pose(path: &Path) -> Result<UsedPose> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let read = parse_pose(&text, path)?;
    let v: Value =
        serde_json::from_str(&text).map_err(|e| Error::input(path, format!("not JSON: {e}")))?;
    if let Some(s) = v.get("status").and_then(Value::as_str) {
        if s != "ok" {
            return Err(Error::input(
                path,
                format!("status {s:?}: not a pose to use"),
            ));
        }
    }
    let quality = v.get("quality").cloned().unwrap_or(Value::Null);
    let covariance = pose_covariance_of(&quality).map_err(|e| Error::input(path, e))?;
    let describe = json!({
        "file": path.display().to_string(),
        "timestamp_utc": v.get("timestamp_utc"),
        "tile_id": v.get("tile_id"),
        "crs": v.get("crs"),
        "sigma": quality.get("sigma"),
        "covariance": covariance.is_some(),
    });
    Ok(UsedPose {
        pose: PoseWithCovariance {
            pose: read.pose,
            covariance,
        },
        describe,
        tile_id: v.get("tile_id").and_then(Value::as_str).map(str::to_string),
        crs: read.crs,
    })
}

/// Run `georef`.
pub(super) fn run(a: Args) -> Result<()> {
    if !(a.sigma_px >= 0.0 && a.sigma_px.is_finite()) {
        return Err(Error::Invalid(format!(
            "--sigma-px {}: must be a finite number ≥ 0",
            a.sigma_px
        )));
    }
    if !(a.max_off_nadir > 0.0 && a.max_off_nadir < 90.0) {
        return Err(Error::Invalid(format!(
            "--max-off-nadir {}: must be in (0, 90) degrees",
            a.max_off_nadir
        )));
    }
    if a.plane.is_some_and(|h| !h.is_finite()) {
        return Err(Error::Invalid("--plane: must be a finite height".into()));
    }
    let need_config =
        a.pose.is_none() || a.camera.is_none() || (a.tiles.is_none() && a.plane.is_none());
    let cfg = if need_config {
        Some(Config::load(&a.config)?)
    } else {
        None
    };
    let pose_path = a
        .pose
        .clone()
        .or_else(|| cfg.as_ref().map(|c| c.output.pose.clone()))
        .unwrap_or_default();
    let used = read_used_pose(&pose_path)?;
    let camera: Camera = match (&a.camera, &cfg) {
        (Some(p), _) => load_camera(p)?,
        (None, Some(c)) => match (&c.camera.intrinsics_file, &c.camera.intrinsics) {
            (Some(p), _) => load_camera(p)?,
            (None, Some(cam)) => cam.clone(),
            (None, None) => {
                return Err(Error::config(
                    &a.config,
                    "[camera]: no intrinsics-file or [camera.intrinsics]",
                ))
            }
        },
        (None, None) => unreachable_config()?,
    };
    let pixels = read_pixels(a.pixels.as_deref())?;
    let params = Params {
        max_off_nadir_deg: a.max_off_nadir,
        sigma_px: a.sigma_px,
        wgs84: true,
    };
    let tile;
    let (surface, crs, tile_desc) = match a.plane {
        Some(h) => (
            Surface::Plane(h),
            used.crs.unwrap_or(Crs::Local),
            json!({"plane_m": h}),
        ),
        None => {
            let tiles = a
                .tiles
                .clone()
                .or_else(|| cfg.as_ref().map(|c| c.map.tiles.clone()))
                .unwrap_or_default();
            let dir = tile_dir(&tiles, used.tile_id.as_deref(), &pose_path)?;
            tile = load_tile(&dir)?;
            let crs = tile.height.grid.crs;
            if let Some(pc) = used.crs {
                if pc != crs {
                    return Err(Error::input(
                        &pose_path,
                        format!("crs {pc} differs from tile {}'s {crs}", tile.id),
                    ));
                }
            }
            let s = HeightSurface::new(&tile.height)
                .ok_or_else(|| Error::input(&dir, "height layer has no valid heights"))?;
            (Surface::Heights(s), crs, json!({"tile_id": tile.id}))
        }
    };
    let points = georef::georef_batch(&camera, &used.pose, &surface, crs, &pixels, &params);
    let text = match a.format {
        Format::Csv => to_csv(&pixels, &points),
        Format::Json => {
            let doc = json!({
                "schema": "infraloc.georef.v1",
                "pose": used.describe,
                "surface": tile_desc,
                "crs": crs.to_string(),
                "points": pixels.iter().zip(&points).map(|(p, m)| record(*p, m)).collect::<Vec<_>>(),
            });
            let mut s = serde_json::to_string_pretty(&doc).unwrap_or_default();
            s.push('\n');
            s
        }
    };
    let stdout = std::io::stdout();
    let mut lock = stdout.lock();
    lock.write_all(text.as_bytes())
        .and_then(|_| lock.flush())
        .map_err(|e| Error::io("<stdout>", e))
}

/// Not reached: the config is loaded whenever a flag is missing.
fn unreachable_config<T>() -> Result<T> {
    Err(Error::Invalid("georef: no camera given".into()))
}

/// The tile directory: `tiles` itself when it is one (has a manifest), else `tiles/<tile_id>`.
fn tile_dir(tiles: &Path, tile_id: Option<&str>, pose_path: &Path) -> Result<PathBuf> {
    if tiles.join(crate::map::cache::MANIFEST).is_file() {
        return Ok(tiles.to_path_buf());
    }
    let id = tile_id.ok_or_else(|| {
        Error::input(
            pose_path,
            "no tile_id: give --tiles as the tile's directory, or --plane",
        )
    })?;
    Ok(tiles.join(id))
}

/// Read the pixels from `path` (`-` or `None`: stdin).
fn read_pixels(path: Option<&Path>) -> Result<Vec<[f64; 2]>> {
    let (text, origin) = match path {
        Some(p) if p != Path::new("-") => (
            std::fs::read_to_string(p).map_err(|e| Error::io(p, e))?,
            p.to_path_buf(),
        ),
        _ => {
            let mut s = String::new();
            std::io::stdin()
                .read_to_string(&mut s)
                .map_err(|e| Error::io("<stdin>", e))?;
            (s, PathBuf::from("<stdin>"))
        }
    };
    parse_pixels(&text, &origin)
}

/// Parse CSV rows `u,v[,…]` ([`super::project::parse_rows`]): a NaN or infinite pixel is
/// read, and gets the status `non_finite`.
pub(crate) fn parse_pixels(text: &str, origin: &Path) -> Result<Vec<[f64; 2]>> {
    super::project::parse_rows(text, origin, ["u", "v"])
}

/// The CSV header of [`to_csv`].
pub(crate) const CSV_HEADER: &str =
    "u,v,status,e,n,h,lat,lon,sigma_major_m,sigma_minor_m,angle_deg";

/// CSV text: the header, then one line per pixel (empty fields where the status is not ok).
pub(crate) fn to_csv(pixels: &[[f64; 2]], points: &[MapPoint]) -> String {
    let mut s = String::with_capacity(64 + 120 * points.len());
    s.push_str(CSV_HEADER);
    s.push('\n');
    for (p, m) in pixels.iter().zip(points) {
        s.push_str(&format!("{},{},{}", p[0], p[1], m.status.name()));
        if m.status == Status::Ok {
            let e = m.ellipse();
            let (lat, lon) = m.lat_lon.map_or((String::new(), String::new()), |[a, b]| {
                (format!("{a:.9}"), format!("{b:.9}"))
            });
            s.push_str(&format!(
                ",{:.4},{:.4},{:.4},{lat},{lon},{:.4},{:.4},{:.2}\n",
                m.enh[0], m.enh[1], m.enh[2], e.sigma_major_m, e.sigma_minor_m, e.angle_deg
            ));
        } else {
            s.push_str(",,,,,,,,\n");
        }
    }
    s
}

/// One pixel's JSON record (docs/georef.md).
pub(crate) fn record(px: [f64; 2], m: &MapPoint) -> Value {
    let num = |v: f64| if v.is_finite() { json!(v) } else { Value::Null };
    let mut r = json!({"u": num(px[0]), "v": num(px[1]), "status": m.status.name()});
    if m.status == Status::Ok {
        let Ellipse {
            sigma_major_m,
            sigma_minor_m,
            angle_deg,
        } = m.ellipse();
        r["e"] = json!(m.enh[0]);
        r["n"] = json!(m.enh[1]);
        r["h"] = json!(m.enh[2]);
        if let Some([lat, lon]) = m.lat_lon {
            r["lat"] = json!(lat);
            r["lon"] = json!(lon);
        }
        r["sigma_major_m"] = json!(sigma_major_m);
        r["sigma_minor_m"] = json!(sigma_minor_m);
        r["angle_deg"] = json!(angle_deg);
        r["covariance_enh"] = json!(m.covariance);
        r["range_m"] = json!(m.range_m);
        r["off_nadir_deg"] = json!(m.off_nadir_deg);
    }
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pixels_parse_with_header_and_name_the_bad_line() {
        let p = Path::new("px.csv");
        let v = parse_pixels("u,v,id\n1,2,a\n\n3.5, nan\n", p).unwrap();
        assert_eq!(v[0], [1.0, 2.0]);
        assert!(v[1][1].is_nan());
        assert_eq!(
            parse_pixels("1,2\n1,x\n", p).unwrap_err().to_string(),
            "px.csv: line 2: v is not a number in \"1,x\""
        );
        assert_eq!(
            parse_pixels("7\n", p).unwrap_err().to_string(),
            "px.csv: line 1: expected u,v, found 1 field(s)"
        );
        assert!(parse_pixels("", p).unwrap().is_empty());
        assert!(parse_pixels("u,v\n", p).unwrap().is_empty());
    }
}
