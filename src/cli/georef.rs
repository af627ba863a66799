//! `infraloc georef`: pixels → map points through the served pose (docs/georef.md).
//!
//! A shell over [`crate::geo::georef`]: it reads the pose file, the camera and the pose's tile,
//! reads `u,v` rows (CSV, header optional, from `--pixels` or stdin) and prints one record per
//! row, in order, as CSV or JSON. A pixel without a map point has its status and empty fields;
//! only unreadable inputs fail the command.

use crate::camera::{load_camera, Camera};
use crate::config::Config;
use crate::control::Request;
use crate::error::{Error, Result};
use crate::geo::georef::{self, HeightSurface, Params, PoseWithCovariance, Surface};
use crate::georef::{describe_pose, point_of_record, to_csv, Document, Record, SCHEMA};
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
    /// --pose, --camera and --tiles do not give (not read when all three are given); with
    /// --running, its `[daemon] socket`.
    #[arg(long, default_value = super::DEFAULT_CONFIG)]
    pub config: PathBuf,
    /// Ask the running service (its `georef` request: the pose it serves and the tile it holds,
    /// at most 10 000 pixels) instead of reading the files.
    #[arg(long, conflicts_with_all = ["pose", "camera", "tiles", "plane", "max_off_nadir"])]
    pub running: bool,
    /// With --running: the control socket (default: `[daemon] socket` of --config).
    #[arg(long, requires = "running")]
    pub socket: Option<PathBuf>,
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
    /// σ of the surface's height (m), carried along each ray into the covariance (default: the
    /// height layer's own noise, estimated from the layer; 0 with --plane).
    #[arg(long)]
    pub height_sigma: Option<f64>,
    /// σ (m) of the Gaussian the height layer is smoothed with before rays meet it (default
    /// 0.15; 0: the layer's samples, bilinear; at most 1).
    #[arg(long, conflicts_with_all = ["running", "plane"])]
    pub height_smoothing: Option<f64>,
    /// Largest angle of a ray from nadir, degrees; beyond it a pixel is `grazing` (default 85).
    #[arg(long)]
    pub max_off_nadir: Option<f64>,
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
    let covariance = pose_covariance_of(&quality).map_err(|e| Error::input(path, e.to_string()))?;
    let describe = describe_pose(path, &v, covariance.is_some());
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
        return Err(Error::arg(
            "--sigma-px",
            a.sigma_px,
            "must be a finite number ≥ 0",
        ));
    }
    if let Some(s) = a.height_sigma.filter(|s| !(s.is_finite() && *s >= 0.0)) {
        return Err(Error::arg(
            "--height-sigma",
            s,
            "must be a finite number ≥ 0",
        ));
    }
    let smoothing = a.height_smoothing.unwrap_or(georef::DEFAULT_SMOOTHING_M);
    if !(0.0..=georef::MAX_SMOOTHING_M).contains(&smoothing) {
        return Err(Error::arg(
            "--height-smoothing",
            smoothing,
            format!("must be in [0, {}] metres", georef::MAX_SMOOTHING_M),
        ));
    }
    let max_off_nadir = a.max_off_nadir.unwrap_or(georef::DEFAULT_MAX_OFF_NADIR_DEG);
    if !(max_off_nadir > 0.0 && max_off_nadir < 90.0) {
        return Err(Error::arg(
            "--max-off-nadir",
            max_off_nadir,
            "must be in (0, 90) degrees",
        ));
    }
    if a.running {
        return run_on_service(&a);
    }
    if a.plane.is_some_and(|h| !h.is_finite()) {
        return Err(Error::Usage("--plane: must be a finite height".into()));
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
        (None, Some(c)) => crate::app::config_camera(c, &a.config, None)?,
        (None, None) => unreachable_config()?,
    };
    let pixels = read_pixels(a.pixels.as_deref())?;
    let params = Params {
        max_off_nadir_deg: max_off_nadir,
        sigma_px: a.sigma_px,
        wgs84: true,
        height_sigma_m: a.height_sigma,
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
            let s = HeightSurface::with_smoothing(&tile.height, smoothing)
                .ok_or_else(|| Error::input(&dir, "height layer has no valid heights"))?;
            (
                Surface::Heights(s),
                crs,
                json!({"tile_id": tile.id, "smoothing_m": smoothing}),
            )
        }
    };
    let mut tile_desc = tile_desc;
    tile_desc["height_sigma_m"] = json!(surface.height_sigma_m(&params));
    let points = georef::georef_batch(&camera, &used.pose, &surface, crs, &pixels, &params);
    let text = match a.format {
        Format::Csv => to_csv(&pixels, &points),
        Format::Json => {
            let doc = Document {
                crs: crs.to_string(),
                points: pixels
                    .iter()
                    .zip(&points)
                    .map(|(p, m)| Record::of(*p, m))
                    .collect(),
                pose: used.describe,
                schema: SCHEMA,
                surface: tile_desc,
            };
            let mut s = serde_json::to_string_pretty(&doc).unwrap_or_default();
            s.push('\n');
            s
        }
    };
    write_stdout(&text)
}

fn write_stdout(text: &str) -> Result<()> {
    let stdout = std::io::stdout();
    let mut lock = stdout.lock();
    lock.write_all(text.as_bytes())
        .and_then(|_| lock.flush())
        .map_err(|e| Error::io("<stdout>", e))
}

/// `georef --running`: the pixels to the service's `georef` request, its answer printed as the
/// local command prints its own (the JSON as the service sent it, less `ok`).
fn run_on_service(a: &Args) -> Result<()> {
    let pixels = read_pixels(a.pixels.as_deref())?;
    let req = Request::Georef {
        pixels: pixels
            .iter()
            .map(|p| p.map(|c| c.is_finite().then_some(c)))
            .collect(),
        sigma_px: a.sigma_px,
        height_sigma_m: a.height_sigma,
    };
    let answer = super::tech::georef_running(a.socket.as_deref(), &a.config, req)?;
    let mut doc: Value = answer.parse("georef answer")?;
    let bad = |reason: String| Error::Answer {
        what: "georef answer",
        reason,
    };
    if let Some(o) = doc.as_object_mut() {
        o.remove("ok");
    }
    let text = match a.format {
        Format::Json => {
            let mut s = serde_json::to_string_pretty(&doc).unwrap_or_default();
            s.push('\n');
            s
        }
        Format::Csv => {
            let records = doc["points"]
                .as_array()
                .ok_or_else(|| bad("no points".into()))?;
            let (px, points): (Vec<_>, Vec<_>) = records
                .iter()
                .map(point_of_record)
                .collect::<std::result::Result<Vec<_>, _>>()
                .map_err(bad)?
                .into_iter()
                .unzip();
            to_csv(&px, &points)
        }
    };
    write_stdout(&text)
}

/// Not reached: the config is loaded whenever a flag is missing.
fn unreachable_config<T>() -> Result<T> {
    Err(Error::Usage("georef: no camera given".into()))
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
