//! The node's application layer: one localization run, from a validated [`Config`] and typed
//! [`Overrides`] to a pose document, with no argument parsing and no printing.
//!
//! capture (frames + intrinsics) → GPS prior → tile → [`crate::localize::pipeline`] → `Run`
//! (pose file, report, overlay). `infraloc localize` and `infraloc demo` call it and write the
//! outputs (`Run::write_outputs`); the service calls it and offers the pose to its store. The
//! CLI only turns flags into [`Overrides`] and prints; the service never imports the CLI.

use crate::camera::{import::IntrinsicsSigma, load_camera, Camera, CameraModel};
use crate::capture::load_gray;
use crate::config::{Config, FrameSourceKind, GpsSourceKind, MatcherKind};
use crate::error::{Error, Result};
use crate::localize::frame::Frame;
use crate::localize::init::matcher::{MatchFile, Matcher};
use crate::localize::pipeline::{localize_pooled, Outcome, Params};
use crate::map::cache::{load_covering, SkippedTile, TileRef};
use crate::map::{Crs, Tile};
use crate::persist::write_atomic;
use crate::posefile::{format_utc, PoseFile, PoseQuality};
use crate::stage::StageName;
use image::GrayImage;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

/// What a caller replaces in the config for one run (`infraloc localize`'s flags). The default
/// replaces nothing: the run is the config's, as the service runs it.
#[derive(Debug, Clone, Default)]
pub struct Overrides {
    /// Intrinsics file instead of the config's camera.
    pub camera: Option<PathBuf>,
    /// Frames to use instead of capturing; several are median-filtered.
    pub images: Vec<PathBuf>,
    /// NMEA log for the prior instead of the config's GPS source.
    pub gps_nmea: Option<PathBuf>,
    /// Prior position (lat, lon), WGS84 degrees, already range-checked by the caller; its σ is
    /// `[gps] fallback-sigma-m`.
    pub prior_wgs84: Option<(f64, f64)>,
    /// Tile cache instead of `[map] tiles`.
    pub tiles: Option<PathBuf>,
    /// Simulator `truth.json` to report each stage's errors against.
    pub truth: Option<PathBuf>,
}

/// Where [`Run::write_outputs`] writes; each `None` falls back to the config's `[output]`.
#[derive(Debug, Clone, Default)]
pub(crate) struct Outputs {
    /// Pose file instead of `[output] pose`.
    pub pose: Option<PathBuf>,
    /// Report JSON instead of `[output] report`.
    pub report: Option<PathBuf>,
    /// Overlay PNG instead of `[output] overlay`.
    pub overlay: Option<PathBuf>,
}

impl Outputs {
    /// The files this run writes, each with what named it (the flag when given, else the
    /// config key): pose, then report and overlay when set.
    pub(crate) fn resolve(&self, cfg: &Config) -> Vec<(&'static str, PathBuf)> {
        let pick = |flag: &'static str,
                    key: &'static str,
                    o: &Option<PathBuf>,
                    c: Option<&PathBuf>| {
            match (o, c) {
                (Some(p), _) => Some((flag, p.clone())),
                (None, Some(p)) => Some((key, p.clone())),
                (None, None) => None,
            }
        };
        [
            pick("--out", "[output] pose", &self.pose, Some(&cfg.output.pose)),
            pick(
                "--report",
                "[output] report",
                &self.report,
                cfg.output.report.as_ref(),
            ),
            pick(
                "--overlay",
                "[output] overlay",
                &self.overlay,
                cfg.output.overlay.as_ref(),
            ),
        ]
        .into_iter()
        .flatten()
        .collect()
    }

    /// Check every output before any work (so that a run does not compute for a minute and then
    /// fail to write): not a directory, its directory exists and is writable. Every problem is
    /// reported, each naming the flag or key and the user's path: exit 78 when a config key is
    /// at fault, else 1. Temp files that killed runs left beside the outputs are removed.
    pub(crate) fn check(&self, cfg: &Config, cfg_path: &Path) -> Result<()> {
        let mut found = crate::preflight::Findings::default();
        let mut from_config = false;
        for (name, path) in self.resolve(cfg) {
            let before = found.problems.len();
            crate::preflight::output_path(name, &path, false, &mut found);
            from_config |= found.problems.len() > before && name.starts_with('[');
            crate::persist::remove_stale_temps(&path);
        }
        if found.problems.is_empty() {
            Ok(())
        } else if from_config {
            Error::config_problems(cfg_path, found.problems)
        } else {
            Err(Error::Usage(found.problems.join("; ")))
        }
    }
}

/// Everything a localization run produced (used by `localize`, `demo` and the service).
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
    /// The pose document.
    pub pose_file: PoseFile,
    /// The report.
    pub report: Value,
    /// Tiles of the cache skipped as unreadable (the run went on without them).
    pub skipped_tiles: Vec<SkippedTile>,
}

fn frames(ov: &Overrides, cfg: &Config, cfg_path: &Path) -> Result<Vec<GrayImage>> {
    if !ov.images.is_empty() {
        return load_grays(&ov.images);
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
            load_grays(&files)
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

/// The gray images of `paths`, in order, decoded in parallel (a 5 MP PNG takes tens of
/// milliseconds, and localization waits for all of them); the first failing path's error, as a
/// serial loop would report it.
fn load_grays(paths: &[PathBuf]) -> Result<Vec<GrayImage>> {
    use rayon::prelude::*;
    let decoded: Vec<Result<GrayImage>> = paths.par_iter().map(|p| load_gray(p)).collect();
    decoded.into_iter().collect()
}

/// The prior as (lat, lon, σ m) and a JSON description of where it came from.
fn prior(ov: &Overrides, cfg: &Config, cancel: &AtomicBool) -> Result<((f64, f64, f64), Value)> {
    if let Some((lat, lon)) = ov.prior_wgs84 {
        let sigma = cfg.gps.fallback_sigma_m;
        return Ok((
            (lat, lon, sigma),
            json!({"source": "command-line", "lat": lat, "lon": lon, "sigma_m": sigma}),
        ));
    }
    let mut g = cfg.gps.clone();
    if let Some(path) = &ov.gps_nmea {
        g.source = GpsSourceKind::NmeaFile;
        g.path = Some(path.clone());
    }
    let outcome = crate::gps_serial::acquire_prior_unless(&g, cancel)?;
    let desc = serde_json::to_value(&outcome).unwrap_or(Value::Null);
    let pos = outcome.position().ok_or_else(|| {
        let why = match &outcome {
            crate::gnss::prior::PriorOutcome::None { reason } => reason.as_str(),
            _ => "no position",
        };
        Error::stage(
            crate::stage::StageName::Prior,
            format!("no position: {why}; and no [gps] fallback-wgs84 is set"),
        )
    })?;
    Ok((pos, desc))
}

/// The camera intrinsics: `camera` when given, else the config's `intrinsics-file` or its
/// inline `[camera.intrinsics]` (`cfg_path` names the config in the error when it has neither).
pub fn config_camera(cfg: &Config, cfg_path: &Path, camera: Option<&Path>) -> Result<Camera> {
    match (camera, &cfg.camera.intrinsics_file, &cfg.camera.intrinsics) {
        (Some(p), _, _) => load_camera(p),
        (None, Some(p), _) => load_camera(p),
        (None, None, Some(c)) => Ok(c.clone()),
        (None, None, None) => Err(Error::config(
            cfg_path,
            "[camera]: no intrinsics-file or [camera.intrinsics]",
        )),
    }
}

/// The camera intrinsics and the (temporally median-filtered) frame under `cfg` (read from
/// `cfg_path`, which errors name) and `ov`, checked to agree in size. `progress(Capture)` is
/// called before frames are taken.
pub fn camera_and_frame(
    cfg: &Config,
    cfg_path: &Path,
    ov: &Overrides,
    progress: &dyn Fn(StageName),
) -> Result<(Camera, GrayImage)> {
    let camera = config_camera(cfg, cfg_path, ov.camera.as_deref())?;
    progress(StageName::Capture);
    let frames = frames(ov, cfg, cfg_path)?;
    let image = if frames.len() == 1 {
        frames.into_iter().next().unwrap_or_default()
    } else {
        crate::capture::temporal_median(&frames)?
    };
    if (image.width(), image.height()) != (camera.width(), camera.height()) {
        return Err(Error::stage(
            StageName::Capture,
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

/// One localization under `cfg` (already loaded and validated from `cfg_path`) with `ov`
/// applied, writing nothing: the caller decides where the pose goes (`localize` writes it, the
/// service offers it to its pose store). `progress` is told each stage as the run reaches it:
/// `capture`, `prior`, `tile`, `pnp`, `mi` (the prior and tile are acquired from the start,
/// beside the capture; their stages are told once the frames are in).
pub(crate) fn run(
    cfg: &Config,
    cfg_path: &Path,
    ov: &Overrides,
    progress: &dyn Fn(StageName),
) -> Result<Run> {
    run_pooled(cfg, cfg_path, ov, progress, None)
}

/// The service's frames of earlier runs for one run ([`run_pooled`]).
pub(crate) struct Pool<'a> {
    /// Where the frames are stored.
    pub store: &'a crate::frames::FrameStore,
    /// The run's time, Unix seconds: its frame is stored under it, and stored frames within the
    /// store's spacing of it are not pooled.
    pub now_unix_s: i64,
    /// The stored frames the run pooled, once its frame is in (set even when the run fails
    /// later, so that the service can say which frames a refused run had).
    pub used: std::sync::Mutex<Vec<crate::frames::FrameEntry>>,
}

/// [`run`] with the frames of earlier runs pooled into the refinement
/// ([`crate::localize::pipeline::localize_pooled`]). Once the frame is captured, the stored
/// frames that fit the camera are loaded (those that do not are skipped with one warning each)
/// and the run's own frame is stored, before anything can refuse it: a refused run leaves its
/// frame for the next. A frame that cannot be stored costs a warning, not the run.
pub(crate) fn run_pooled(
    cfg: &Config,
    cfg_path: &Path,
    ov: &Overrides,
    progress: &dyn Fn(StageName),
    pool: Option<&Pool<'_>>,
) -> Result<Run> {
    let t_start = Instant::now();
    // The matcher's file first: a missing or malformed one fails before the frames are captured.
    let matcher = matcher_from_config(cfg)?;
    let tiles = ov.tiles.clone().unwrap_or_else(|| cfg.map.tiles.clone());
    let mi_radius_m = Params::default().mi_radius_m;
    // The prior and its tile do not depend on the frames, so they are acquired while the frames
    // are captured: a receiver's averaging window and a camera's settle and frame intervals are
    // each seconds, and the tile's decoding fills the pool while the last frames decode. This
    // thread still reports the stages in their order and their errors in that order (capture,
    // then prior, then tile). However this side ends (a result, an error, a panic) the
    // acquisition is cancelled, and it is joined before the error or panic goes on: a receiver
    // stops within one read; a tile already loading finishes its decode first.
    let cancel = AtomicBool::new(false);
    let (camera, image, earlier, located, intrinsics_sigma) = std::thread::scope(|s| {
        let (tx, rx) = std::sync::mpsc::channel();
        let (cancel, tiles) = (&cancel, &tiles);
        let acquire = s.spawn(move || {
            let prior = prior(ov, cfg, cancel);
            let at = prior.as_ref().ok().map(|p| p.0);
            // The receiver is gone, or the flag set, only when the capture side ended early.
            if tx.send(Located::Prior(prior)).is_err() || cancel.load(Ordering::Relaxed) {
                return;
            }
            if let Some((lat, lon, _)) = at {
                let tile = load_covering(tiles, lat, lon, cfg.map.search_margin_m, mi_radius_m)
                    .map(Box::new);
                let _ = tx.send(Located::Tile(tile));
            }
        });
        let received = {
            let _cancel = CancelOnDrop(cancel);
            capture_and_receive(cfg, cfg_path, ov, progress, pool, rx)
        };
        // A panicked acquisition shows as a `lost` stage error above; joined here, the scope
        // does not raise it again.
        let _ = acquire.join();
        received
    })?;
    let (((lat, lon, sigma), prior_desc), located_tile) = located;
    let (tile, tref) = *located_tile;
    let params = Params {
        matcher,
        quality: crate::localize::refine::quality::QualityConfig {
            intrinsics_sigma,
            ..cfg.quality
        },
        ..Params::default()
    };
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
    let earlier_frames = earlier
        .iter()
        .map(|f| Frame::new(&camera, f.image.as_raw()))
        .collect::<std::result::Result<Vec<_>, _>>()?;
    let outcome = localize_pooled(
        &Frame::new(&camera, image.as_raw())?,
        &earlier_frames,
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
    let quality = LocalizedQuality {
        refinement: q,
        score: q.nmi,
        pnp_inliers: outcome.init.inliers,
        pnp_rms_px: outcome.init.rms_px,
    };
    pf.quality = PoseQuality::from_value(serde_json::to_value(quality).unwrap_or(json!({})));
    pf.stages = outcome.stages.iter().map(|s| s.to_json()).collect();
    pf.stages[0]["source"] = prior_desc.clone();

    let mut report = json!({
        "config": cfg_path,
        "tile_id": tile.id,
        "prior": prior_desc,
        "stages": pf.stages,
        "seconds_total": t_start.elapsed().as_secs_f64(),
    });
    if !tref.skipped.is_empty() {
        report["skipped_tiles"] = json!(tref.skipped);
    }
    if pool.is_some() {
        report["pooled_frames"] = json!(earlier.iter().map(|f| &f.entry).collect::<Vec<_>>());
    }
    if let Some(t) = &ov.truth {
        let text = std::fs::read_to_string(t).map_err(|e| Error::io(t, e))?;
        report["truth"] =
            crate::eval::truth_eval::truth_errors(&text, t, &camera, &outcome.stages)?;
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

/// The capture side of [`run`]: the camera and frame, then the prior and the tile as the
/// acquisition beside it sends them (`rx`), the stages reported and errors returned in the order
/// capture, prior, tile. Dropping `rx` on the way out tells the acquisition nobody waits.
fn capture_and_receive(
    cfg: &Config,
    cfg_path: &Path,
    ov: &Overrides,
    progress: &dyn Fn(StageName),
    pool: Option<&Pool<'_>>,
    rx: std::sync::mpsc::Receiver<Located>,
) -> Result<Captured> {
    let (camera, image) = camera_and_frame(cfg, cfg_path, ov, progress)?;
    let earlier = pool.map_or_else(Vec::new, |p| pool_and_store(p, &camera, &image));
    // Only a panic ends the acquisition without sending.
    let lost =
        |stage: StageName| Error::stage(stage, "the acquisition beside the capture ended early");
    progress(StageName::Prior);
    let prior = match rx.recv() {
        Ok(Located::Prior(p)) => p?,
        _ => return Err(lost(StageName::Prior)),
    };
    progress(StageName::Tile);
    // The camera file's stated intrinsics uncertainty goes into the pose's covariance.
    let intrinsics_sigma = match (&ov.camera, &cfg.camera.intrinsics_file) {
        (Some(p), _) | (None, Some(p)) => crate::camera::load_intrinsics_sigma(p)?,
        (None, None) => None,
    };
    let tile = match rx.recv() {
        Ok(Located::Tile(t)) => t?,
        _ => return Err(lost(StageName::Tile)),
    };
    Ok((camera, image, earlier, (prior, tile), intrinsics_sigma))
}

/// The stored frames `p` pools for `camera`, then `image` stored for the runs after this one;
/// every frame skipped, dropped or not stored is logged in one line.
fn pool_and_store(
    p: &Pool<'_>,
    camera: &Camera,
    image: &GrayImage,
) -> Vec<crate::frames::StoredFrame> {
    let (earlier, skipped) = p.store.pool(camera, p.now_unix_s);
    for line in skipped {
        tracing::warn!("{line}");
    }
    match p.store.put(
        image,
        &crate::frames::camera_fingerprint(camera),
        p.now_unix_s,
    ) {
        Ok(dropped) => dropped.iter().for_each(|l| tracing::info!("{l}")),
        Err(e) => tracing::warn!("this run's frame is not stored for later runs: {e}"),
    }
    *p.used.lock().unwrap_or_else(|e| e.into_inner()) =
        earlier.iter().map(|f| f.entry.clone()).collect();
    earlier
}

/// What [`capture_and_receive`] hands on: the camera, its frame, the stored frames pooled with
/// it, the prior with its tile, and the intrinsics' stated σ.
type Captured = (
    Camera,
    GrayImage,
    Vec<crate::frames::StoredFrame>,
    AcquiredPrior,
    Option<IntrinsicsSigma>,
);

/// The prior (lat, lon, σ m; where it came from) and the tile covering it.
type AcquiredPrior = (((f64, f64, f64), Value), Box<(Tile, TileRef)>);

/// Sets its flag when dropped: every way out of the capture side, a panic included, ends the
/// acquisition's wait.
struct CancelOnDrop<'a>(&'a AtomicBool);

impl Drop for CancelOnDrop<'_> {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Relaxed);
    }
}

/// What the acquisition beside the capture in [`run`] hands over, in this order.
enum Located {
    /// The prior as (lat, lon, σ m) and where it came from.
    Prior(Result<((f64, f64, f64), Value)>),
    /// The tile covering it, loaded.
    Tile(Result<Box<(Tile, TileRef)>>),
}

/// The pose file's `quality` block as a localization writes it: the refinement's figures with
/// the initialization's beside them. Stored through a JSON value, so its keys stay sorted.
#[derive(serde::Serialize)]
struct LocalizedQuality<'a> {
    #[serde(flatten)]
    refinement: &'a crate::localize::refine::quality::Quality,
    /// The pose store compares results by it: the MI optimum's NMI.
    score: f64,
    /// The final PnP's inliers.
    pnp_inliers: usize,
    /// Its reprojection RMS, px (`null` for a verified sweep pose, whose RMS is NaN).
    pnp_rms_px: f64,
}

/// The initialization matcher `[init]` names, its file read: `None` for the built-in one.
fn matcher_from_config(cfg: &Config) -> Result<Option<Arc<dyn Matcher>>> {
    match (cfg.init.matcher, &cfg.init.matcher_path) {
        (MatcherKind::DenseSweep, _) => Ok(None),
        (MatcherKind::MatchFile, None) => Err(Error::stage(
            StageName::Pnp,
            "matcher = \"match-file\" needs matcher-path",
        )),
        (MatcherKind::MatchFile, Some(path)) => {
            let text =
                std::fs::read_to_string(path).map_err(|e| Error::input(path, e.to_string()))?;
            let m = MatchFile::parse(&text, path).map_err(|e| Error::input(path, e.to_string()))?;
            Ok(Some(Arc::new(m)))
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

    /// Write the report and overlay, then the pose file (each atomically), where `out` says or
    /// else where `cfg`'s `[output]` says (the report and overlay only when one of them names a
    /// path). The pose comes last, so an error (a non-zero exit) means the pose file is
    /// untouched; check the paths first with [`Outputs::check`].
    pub(crate) fn write_outputs(&self, cfg: &Config, out: &Outputs) -> Result<()> {
        self.write_side_outputs(
            out.report.as_ref().or(cfg.output.report.as_ref()),
            out.overlay.as_ref().or(cfg.output.overlay.as_ref()),
        )?;
        let pose = out.pose.as_ref().unwrap_or(&cfg.output.pose);
        write_atomic(pose, self.pose_file.to_json().as_bytes())
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
