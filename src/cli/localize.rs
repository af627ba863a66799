//! `infraloc localize`: the full two-step pipeline, one shot (contracts §6).

use crate::camera::{import::load_camera, Camera, CameraModel};
use crate::config::{Config, FrameSourceKind, GpsSourceKind};
use crate::error::{Error, Result};
use crate::localize::pipeline::{localize, Outcome, Params};
use crate::map::cache::{load_covering, SkippedTile};
use crate::map::{Crs, Tile};
use crate::persist::write_atomic;
use crate::posefile::{format_utc, PoseFile};
use image::GrayImage;
use serde_json::{json, Value};
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Arguments of `localize`.
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// Configuration file (a simulated scene's `infraloc.toml` localizes it with no other flags).
    #[arg(long, default_value = super::DEFAULT_CONFIG)]
    pub config: PathBuf,
    /// Intrinsics file (overrides the config's camera).
    #[arg(long)]
    pub camera: Option<PathBuf>,
    /// Frame(s) to use instead of capturing; several are median-filtered.
    #[arg(long = "image")]
    pub images: Vec<PathBuf>,
    /// NMEA log for the prior (overrides the config's GPS source).
    #[arg(long, conflicts_with = "prior_wgs84")]
    pub gps_nmea: Option<PathBuf>,
    /// Prior position `LAT,LON` (overrides the config's GPS source).
    #[arg(long)]
    pub prior_wgs84: Option<String>,
    /// Tile cache (overrides `[map] tiles`).
    #[arg(long)]
    pub tiles: Option<PathBuf>,
    /// Pose file to write (overrides `[output] pose`).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Overlay PNG: LiDAR points (cyan) over the frame at the PnP pose (left) and at the final
    /// pose (right).
    #[arg(long)]
    pub overlay: Option<PathBuf>,
    /// Report JSON: per-stage poses, timings, evaluation counts, errors vs truth.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Ground truth (a simulator `truth.json`) to report errors against.
    #[arg(long)]
    pub truth: Option<PathBuf>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
}

/// Everything a localization run produced (used by `localize`, `demo` and the daemon).
pub(crate) struct Run {
    /// Pipeline outcome.
    pub outcome: Outcome,
    /// Tile used.
    pub tile: Tile,
    /// Median frame.
    pub image: GrayImage,
    /// Camera intrinsics used.
    pub camera: Camera,
    /// Radius of the LiDAR points drawn in the overlay, metres.
    pub mi_radius_m: f64,
    /// The pose document written.
    pub pose_file: PoseFile,
    /// The report.
    pub report: Value,
    /// Tiles of the cache skipped as unreadable (the run went on without them).
    pub skipped_tiles: Vec<SkippedTile>,
}

fn load_gray(path: &Path) -> Result<GrayImage> {
    let img =
        image::open(path).map_err(|e| Error::input(path, format!("cannot read image: {e}")))?;
    Ok(img.to_luma8())
}

fn frames(a: &Args, cfg: &Config, cfg_path: &Path) -> Result<Vec<GrayImage>> {
    if !a.images.is_empty() {
        return a.images.iter().map(|p| load_gray(p)).collect();
    }
    let c = &cfg.camera;
    match c.source {
        // Recorded frames are read as they are: no exposure settling, no pacing.
        FrameSourceKind::File => {
            let path = c.frames.as_ref().ok_or_else(|| {
                Error::config(cfg_path, "[camera] source = \"file\" needs frames")
            })?;
            let mut src = crate::capture::FileSource::new(path);
            crate::capture::FrameSource::open(&mut src)
                .map_err(|e| Error::input(path, e.detail))?;
            let files: Vec<PathBuf> = src
                .files()
                .iter()
                .take(c.frame_count.max(1) as usize)
                .cloned()
                .collect();
            if files.is_empty() {
                return Err(Error::input(path, "no image files"));
            }
            files.iter().map(|p| load_gray(p)).collect()
        }
        _ => {
            let mut src = crate::capture::source_from_config(c)?;
            let settings = crate::capture::CaptureSettings::from_config(c);
            let cap = crate::capture::capture(
                src.as_mut(),
                &settings,
                &crate::capture::SystemClock::default(),
            )?;
            Ok(cap.frames.into_iter().map(|f| f.image).collect())
        }
    }
}

/// The prior as (lat, lon, σ m) and a JSON description of where it came from.
fn prior(a: &Args, cfg: &Config, cfg_path: &Path) -> Result<((f64, f64, f64), Value)> {
    if let Some(s) = &a.prior_wgs84 {
        let [lat, lon] = super::parse_list::<2>("--prior-wgs84", s)?;
        if !(lat.abs() <= 90.0 && lon.abs() <= 180.0) {
            return Err(Error::Invalid(format!(
                "--prior-wgs84 {s}: not a WGS84 position"
            )));
        }
        let sigma = cfg.gps.fallback_sigma_m;
        return Ok((
            (lat, lon, sigma),
            json!({"source": "command-line", "lat": lat, "lon": lon, "sigma_m": sigma}),
        ));
    }
    let mut g = cfg.gps.clone();
    if let Some(path) = &a.gps_nmea {
        g.source = GpsSourceKind::NmeaFile;
        g.path = Some(path.clone());
    }
    let _ = cfg_path;
    let outcome = crate::gps_serial::acquire_prior(&g)?;
    let desc = serde_json::to_value(&outcome).unwrap_or(Value::Null);
    let pos = outcome.position().ok_or_else(|| {
        let why = match &outcome {
            crate::gnss::prior::PriorOutcome::None { reason } => reason.as_str(),
            _ => "no position",
        };
        Error::stage(
            "prior",
            format!("no position: {why}; and no [gps] fallback-wgs84 is set"),
        )
    })?;
    Ok((pos, desc))
}

/// Run the whole pipeline for `a`, writing pose/report/overlay as configured, with the stages
/// shown on stderr while they run when stderr is a terminal.
pub(crate) fn run_pipeline(a: &Args) -> Result<Run> {
    if let Some(n) = a.threads {
        // Only the first call in a process can size the global pool; later calls keep it.
        let _ = rayon::ThreadPoolBuilder::new()
            .num_threads(n.max(1))
            .build_global();
    }
    let cfg = Config::load(&a.config)?;
    cfg.validate(&a.config)?;
    let stderr = std::io::stderr();
    let tty = stderr.is_terminal();
    let run = super::progress::with_progress(stderr, tty, |progress| compute(a, &cfg, progress))?;
    let out = a.out.clone().unwrap_or_else(|| cfg.output.pose.clone());
    write_atomic(&out, run.pose_file.to_json().as_bytes())?;
    run.write_side_outputs(
        a.report.as_ref().or(cfg.output.report.as_ref()),
        a.overlay.as_ref().or(cfg.output.overlay.as_ref()),
    )?;
    Ok(run)
}

/// The camera intrinsics and the (temporally median-filtered) frame for `a` under `cfg`, checked
/// to agree in size. `progress("capture")` is called before frames are taken.
pub(crate) fn camera_and_frame(
    a: &Args,
    cfg: &Config,
    progress: &dyn Fn(&str),
) -> Result<(Camera, GrayImage)> {
    let camera = match (
        &a.camera,
        &cfg.camera.intrinsics_file,
        &cfg.camera.intrinsics,
    ) {
        (Some(p), _, _) | (None, Some(p), _) => load_camera(p)?,
        (None, None, Some(c)) => c.clone(),
        (None, None, None) => {
            return Err(Error::config(
                &a.config,
                "[camera]: no intrinsics-file or [camera.intrinsics]",
            ))
        }
    };
    progress("capture");
    let frames = frames(a, cfg, &a.config)?;
    let image = if frames.len() == 1 {
        frames.into_iter().next().unwrap_or_default()
    } else {
        crate::capture::temporal_median(&frames)?
    };
    if (image.width(), image.height()) != (camera.width(), camera.height()) {
        return Err(Error::stage(
            "capture",
            format!(
                "frame is {}×{}, camera intrinsics are {}×{}",
                image.width(),
                image.height(),
                camera.width(),
                camera.height()
            ),
        ));
    }
    Ok((camera, image))
}

/// The pipeline for `a` under `cfg` (already loaded and validated), writing nothing: the caller
/// decides where the pose goes (`localize` writes it, the daemon offers it to its pose store).
/// `progress` is told each stage as it starts: `capture`, `prior`, `tile`, `pnp`, `mi`.
pub(crate) fn compute(a: &Args, cfg: &Config, progress: &dyn Fn(&str)) -> Result<Run> {
    let t_start = Instant::now();
    // The matcher's file first: a missing or malformed one fails before the frames are captured.
    let matcher = matcher_from_config(cfg)?;
    let (camera, image) = camera_and_frame(a, cfg, progress)?;
    progress("prior");
    let ((lat, lon, sigma), prior_desc) = prior(a, cfg, &a.config)?;
    progress("tile");
    let tiles = a.tiles.clone().unwrap_or_else(|| cfg.map.tiles.clone());
    let params = Params {
        matcher,
        ..Params::default()
    };
    // The covering tile's LiDAR layers must hold data around the prior: a damaged layer is a
    // map fault, not a PnP or MI failure. Unreadable tiles elsewhere are skipped and reported.
    let (tile, tref) = load_covering(
        &tiles,
        lat,
        lon,
        cfg.map.search_margin_m,
        params.mi_radius_m,
    )?;
    let crs = tile.reflectivity.grid.crs;
    let (px, py) = match crs {
        Crs::Epsg(_) => crate::geo::wgs84_to_map(crs, lat, lon)?,
        Crs::Local => {
            return Err(Error::input(
                &tref.dir,
                "tile CRS is LOCAL: a WGS84 prior cannot be placed in it",
            ))
        }
    };
    let clock = |t: Instant| move || t.elapsed().as_secs_f64();
    let outcome = localize(
        &camera,
        image.as_raw(),
        &tile,
        (px, py),
        sigma,
        &params,
        &clock(Instant::now()),
        progress,
    )?;

    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap_or_default();
    let mut pf = PoseFile::new(
        &outcome.pose,
        crs,
        &tile.id,
        format_utc(now.as_secs() as i64, None),
    );
    pf.intrinsics = serde_json::to_value(&camera).unwrap_or(Value::Null);
    let q = &outcome.refinement.quality;
    let mut quality = serde_json::to_value(q).unwrap_or(json!({}));
    // The pose store compares results by `score`: the MI optimum's NMI.
    quality["score"] = json!(q.nmi);
    quality["pnp_inliers"] = json!(outcome.init.inliers);
    quality["pnp_rms_px"] = json!(outcome.init.rms_px);
    pf.quality = quality;
    pf.stages = outcome.stages.iter().map(|s| s.to_json()).collect();
    pf.stages[0]["source"] = prior_desc.clone();

    let mut report = json!({
        "config": a.config,
        "tile_id": tile.id,
        "prior": prior_desc,
        "stages": pf.stages,
        "seconds_total": t_start.elapsed().as_secs_f64(),
    });
    if !tref.skipped.is_empty() {
        report["skipped_tiles"] = json!(tref.skipped);
    }
    if let Some(t) = &a.truth {
        report["truth"] = truth_errors(t, &camera, &outcome)?;
    }
    Ok(Run {
        outcome,
        tile,
        image,
        camera,
        mi_radius_m: params.mi_radius_m,
        pose_file: pf,
        report,
        skipped_tiles: tref.skipped,
    })
}

/// The initialization matcher `[init]` names, its file read: `None` for the built-in one.
fn matcher_from_config(
    cfg: &Config,
) -> Result<Option<std::sync::Arc<dyn crate::localize::matcher::Matcher>>> {
    use crate::config::MatcherKind;
    match (cfg.init.matcher, &cfg.init.matcher_path) {
        (MatcherKind::DenseSweep, _) => Ok(None),
        (MatcherKind::MatchFile, None) => Err(Error::stage(
            "init",
            "matcher = \"match-file\" needs matcher-path",
        )),
        (MatcherKind::MatchFile, Some(path)) => {
            let text =
                std::fs::read_to_string(path).map_err(|e| Error::input(path, e.to_string()))?;
            let m = crate::localize::matcher::MatchFile::parse(&text, path)
                .map_err(|e| Error::input(path, e))?;
            Ok(Some(std::sync::Arc::new(m)))
        }
    }
}

impl Args {
    /// Arguments that take everything from the config file `config` (what the daemon runs).
    pub(crate) fn from_config(config: &Path) -> Args {
        Args {
            config: config.to_path_buf(),
            camera: None,
            images: Vec::new(),
            gps_nmea: None,
            prior_wgs84: None,
            tiles: None,
            out: None,
            overlay: None,
            report: None,
            truth: None,
            threads: None,
        }
    }
}

impl Run {
    /// The technician's picture: the tile's LiDAR points over the median frame, projected at the
    /// PnP pose (left panel, "before") and at the final pose (right panel, "after"), as PNG
    /// bytes ([`crate::viz::before_after`]).
    pub(crate) fn overlay_png(&self) -> Result<Vec<u8>> {
        let c = self.outcome.pose.center();
        let pts = crate::map::ground_points(&self.tile, (c.x, c.y), self.mi_radius_m);
        crate::viz::before_after_png(
            &self.image,
            &self.camera,
            &self.outcome.init.pose,
            &self.outcome.pose,
            &pts,
        )
    }

    /// Write the report JSON and the overlay PNG where asked (each atomically).
    pub(crate) fn write_side_outputs(
        &self,
        report: Option<&PathBuf>,
        overlay: Option<&PathBuf>,
    ) -> Result<()> {
        if let Some(p) = report {
            let text = serde_json::to_string_pretty(&self.report).unwrap_or_default();
            write_atomic(p, text.as_bytes())?;
        }
        if let Some(p) = overlay {
            write_atomic(p, &self.overlay_png()?)?;
        }
        Ok(())
    }
}

/// Errors of each stage's pose against a simulator `truth.json`.
fn truth_errors(path: &Path, camera: &Camera, o: &Outcome) -> Result<Value> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    crate::localize::pipeline::truth_errors(&text, path, camera, &o.stages)
}

/// Run `localize`: write the outputs and print a one-line summary.
pub fn run(a: Args) -> Result<()> {
    let r = run_pipeline(&a)?;
    let (y, p, ro) = r.outcome.pose.yaw_pitch_roll();
    let c = r.outcome.pose.center();
    println!(
        "pose ok: tile {} centre ({:.3}, {:.3}, {:.3}) yaw {:.3}° pitch {:.3}° roll {:.3}°  NMI {:.4}",
        r.tile.id, c.x, c.y, c.z, y.to_degrees(), p.to_degrees(), ro.to_degrees(), r.outcome.refinement.quality.nmi
    );
    if let Some(t) = r.report.get("truth") {
        println!("vs truth: {t}");
    }
    let _ = &r.pose_file;
    let _ = &r.image;
    Ok(())
}
