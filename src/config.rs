//! The TOML configuration: kebab-case keys, unknown keys rejected, relative paths resolved against
//! the config file's directory. [`Config::check`] returns semantic warnings that do not stop the
//! node but that a technician should see (`infraloc validate`).

use crate::camera::Camera;
use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Whole configuration file.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", deny_unknown_fields)]
pub struct Config {
    /// Camera intrinsics and frame source.
    #[serde(default)]
    pub camera: CameraConfig,
    /// GNSS receiver / position prior.
    #[serde(default)]
    pub gps: GpsConfig,
    /// Map tile cache.
    #[serde(default)]
    pub map: MapConfig,
    /// Where results go.
    #[serde(default)]
    pub output: OutputConfig,
    /// The service (`infraloc daemon`): control socket, schedules, drift check.
    #[serde(default)]
    pub daemon: DaemonConfig,
    /// The MI result's gate: σ limits and the grid search's checks.
    #[serde(default)]
    pub quality: crate::localize::refine::quality::QualityConfig,
    /// Initialization: which matcher pairs the frame with the map.
    #[serde(default)]
    pub init: InitConfig,
    /// `[refine]`, the retired switch between the local estimators (there is one now): still
    /// read, so that an older config keeps its node running, and named by [`Config::check`];
    /// never written.
    #[serde(default, skip_serializing)]
    pub refine: Option<serde::de::IgnoredAny>,
}

/// Which matcher initialization uses (`[init] matcher`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum MatcherKind {
    /// The built-in, learning-free satellite matching (dense orientation sweep + patch stages).
    #[default]
    DenseSweep,
    /// Correspondences from a CSV file `u,v,x,y[,z]` (`matcher-path`): made offline, e.g. by a
    /// learned matcher on another machine, or surveyed marks picked in the image.
    MatchFile,
}

/// `[init]`: the initialization's matcher. A learned matcher would be one more kind, loading its
/// weights from `matcher-path` (docs/architecture.md, "Matchers").
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", deny_unknown_fields, default)]
pub struct InitConfig {
    /// The matcher.
    pub matcher: MatcherKind,
    /// The matcher's file: the correspondences of `match-file` (a learned matcher's weights).
    pub matcher_path: Option<PathBuf>,
}

/// Where frames come from.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FrameSourceKind {
    /// An image file or a directory of images (replay, tests, simulated scenes).
    #[default]
    File,
    /// A V4L2 device (`/dev/videoN`).
    V4l2,
    /// A GigE Vision / USB3 Vision camera through Aravis (cargo feature `aravis`).
    Aravis,
}

impl FrameSourceKind {
    /// The name used in the config file.
    pub(crate) fn name(self) -> &'static str {
        match self {
            FrameSourceKind::File => "file",
            FrameSourceKind::V4l2 => "v4l2",
            FrameSourceKind::Aravis => "aravis",
        }
    }

    /// Whether this build can capture from this kind of source: the camera backends are cargo
    /// features (`v4l`, `aravis`) so that the default build needs no C toolchain or system
    /// library (docs/architecture.md, "Capture backends are cargo features").
    pub(crate) fn compiled_in(self) -> bool {
        match self {
            FrameSourceKind::File => true,
            FrameSourceKind::V4l2 => cfg!(feature = "v4l"),
            FrameSourceKind::Aravis => cfg!(feature = "aravis"),
        }
    }

    /// The one-line problem for a source kind this build lacks: the key, and how to get a build
    /// that has it.
    pub(crate) fn missing_backend_problem(self) -> String {
        match self {
            FrameSourceKind::File => String::new(),
            FrameSourceKind::V4l2 => "[camera] source = \"v4l2\": this build has no V4L2 capture; \
                 install the infraloc .deb or build with `cargo build --release --features v4l` \
                 (needs libclang-dev)"
                .into(),
            FrameSourceKind::Aravis => "[camera] source = \"aravis\": this build has no Aravis \
                 capture; build with `cargo build --release --features aravis` (needs \
                 libaravis-dev)"
                .into(),
        }
    }

    /// Pixel formats (`pixel-format`) this source kind can convert to gray.
    pub(crate) fn pixel_formats(self) -> &'static [&'static str] {
        match self {
            FrameSourceKind::File => &[],
            FrameSourceKind::V4l2 => &["GREY", "Y16", "YUYV", "MJPG"],
            FrameSourceKind::Aravis => &[
                "Mono8", "Mono16", "BayerRG8", "BayerBG8", "BayerGR8", "BayerGB8",
            ],
        }
    }
}

/// `[camera]`: intrinsics (a file, or the inline `[camera.intrinsics]` table) and frame source.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", deny_unknown_fields, default)]
pub struct CameraConfig {
    /// Intrinsics file: OpenCV FileStorage, Kalibr camchain, KITTI-360 MEI YAML or TOML table.
    pub intrinsics_file: Option<PathBuf>,
    /// Inline intrinsics (the native form), used when no file is given.
    pub intrinsics: Option<Camera>,
    /// Frame source kind.
    pub source: FrameSourceKind,
    /// For `source = "file"`: an image, or a directory whose images are read in name order.
    pub frames: Option<PathBuf>,
    /// For `v4l2`: device path; for `aravis`: camera id (empty = first found).
    pub device: Option<String>,
    /// Frames captured per localization (their temporal median removes traffic).
    pub frame_count: u32,
    /// Spacing between captured frames, milliseconds.
    pub frame_interval_ms: u64,
    /// Frames discarded after opening while exposure settles.
    pub settle_frames: u32,
    /// Per-frame timeout, milliseconds.
    pub timeout_ms: u64,
    /// Attempts per frame (first included) before a fault (absent device, timeout, short or
    /// corrupt frame) becomes an error.
    pub retry_attempts: u32,
    /// Wait after the first failed attempt, milliseconds; doubled after each further one
    /// (capped at 30 s).
    pub retry_backoff_ms: u64,
    /// Pixel format to request: v4l2 `GREY`, `Y16`, `YUYV`, `MJPG`; aravis `Mono8`, `Mono16`,
    /// `BayerRG8`, `BayerBG8`, `BayerGR8`, `BayerGB8`. Unset: keep the device's current format
    /// (it must be one of these).
    pub pixel_format: Option<String>,
    /// For `v4l2`: frame size `[width, height]` to request (unset: the device's current size).
    pub resolution: Option<[u32; 2]>,
    /// For `aravis`: sensor region `[x, y, width, height]` (unset: the camera's current one).
    pub region: Option<[u32; 4]>,
    /// For `aravis`: exposure time, microseconds (unset: leave the camera's setting, e.g. auto).
    pub exposure_us: Option<f64>,
    /// For `aravis`: analog gain, dB (unset: leave the camera's setting).
    pub gain_db: Option<f64>,
}

impl Default for CameraConfig {
    fn default() -> Self {
        CameraConfig {
            intrinsics_file: None,
            intrinsics: None,
            source: FrameSourceKind::File,
            frames: None,
            device: None,
            frame_count: 5,
            frame_interval_ms: 1000,
            settle_frames: 5,
            timeout_ms: 2000,
            retry_attempts: 3,
            retry_backoff_ms: 500,
            pixel_format: None,
            resolution: None,
            region: None,
            exposure_us: None,
            gain_db: None,
        }
    }
}

/// Where the position prior comes from.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum GpsSourceKind {
    /// A recorded NMEA 0183 log file.
    #[default]
    NmeaFile,
    /// A live receiver on a serial port.
    Serial,
    /// No receiver: use `fallback-wgs84` (a surveyed position).
    Fixed,
}

/// `[gps]`: receiver and position-prior settings.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", deny_unknown_fields, default)]
pub struct GpsConfig {
    /// Source kind.
    pub source: GpsSourceKind,
    /// For `nmea-file`: the log.
    pub path: Option<PathBuf>,
    /// For `serial`: the device, e.g. `/dev/ttyACM0`.
    pub device: Option<String>,
    /// For `serial`: baud rate.
    pub baud: u32,
    /// Averaging window for the position prior, seconds of fixes.
    pub window_s: f64,
    /// How long to wait for a fix before falling back, seconds.
    pub timeout_s: f64,
    /// Surveyed position `[lat, lon]` used when no fix arrives (or with `source = "fixed"`).
    pub fallback_wgs84: Option<[f64; 2]>,
    /// 1-σ horizontal uncertainty of the fallback position, metres.
    pub fallback_sigma_m: f64,
    /// Fixes with a larger HDOP are left out of the prior.
    pub max_hdop: f64,
    /// Accepted fixes (after outlier rejection) needed for a GNSS prior; fewer → fallback.
    pub min_fixes: usize,
    /// For `serial`: longest wait between reconnect attempts, seconds (back-off doubles up to it).
    pub reconnect_max_s: f64,
}

impl Default for GpsConfig {
    fn default() -> Self {
        GpsConfig {
            source: GpsSourceKind::NmeaFile,
            path: None,
            device: None,
            baud: 9600,
            window_s: 30.0,
            timeout_s: 120.0,
            fallback_wgs84: None,
            fallback_sigma_m: 5.0,
            max_hdop: 10.0,
            min_fixes: 5,
            reconnect_max_s: 30.0,
        }
    }
}

/// `[map]`: the local tile cache.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", deny_unknown_fields, default)]
pub struct MapConfig {
    /// Tile cache directory (docs/interfaces.md, "Tile cache").
    pub tiles: PathBuf,
    /// A tile covers a position if the position is at least this far inside it, metres.
    pub search_margin_m: f64,
}

impl Default for MapConfig {
    fn default() -> Self {
        MapConfig {
            tiles: PathBuf::from("tiles"),
            search_margin_m: 30.0,
        }
    }
}

/// `[output]`: where results are written.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", deny_unknown_fields, default)]
pub struct OutputConfig {
    /// Pose file for the detection pipeline (docs/interfaces.md, "Pose file").
    pub pose: PathBuf,
    /// Optional report JSON.
    pub report: Option<PathBuf>,
    /// Optional overlay PNG.
    pub overlay: Option<PathBuf>,
    /// Pixel step of the georeferencing lookup table the service keeps beside the pose file
    /// (docs/georef.md "Lookup table"); 0: no table.
    pub georef_lut_step_px: u32,
}

impl Default for OutputConfig {
    fn default() -> Self {
        OutputConfig {
            pose: PathBuf::from("pose.json"),
            report: None,
            overlay: None,
            georef_lut_step_px: 4,
        }
    }
}

/// `[daemon]`: the service's control socket, schedules and drift check.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", deny_unknown_fields, default)]
pub struct DaemonConfig {
    /// Control socket of the technician commands (inside systemd's RuntimeDirectory).
    pub socket: PathBuf,
    /// Localization results kept in the history beside the pose file.
    pub history_len: usize,
    /// Re-localize on this period, hours; 0 = only at boot, on trigger and by the systemd timer.
    pub relocalize_interval_h: f64,
    /// After a failed localization, retry after this many seconds …
    pub retry_initial_s: f64,
    /// … doubling up to this many.
    pub retry_max_s: f64,
    /// Drift check period, minutes (0 = off): a narrow MI search around the served pose on fresh
    /// frames; a camera found moved is re-localized.
    pub drift_check_interval_min: f64,
    /// The drift check flags a horizontal shift of at least this, metres …
    pub drift_threshold_m: f64,
    /// … or a yaw change of at least this, degrees.
    pub drift_threshold_deg: f64,
    /// Directory of node_exporter's textfile collector: the service keeps
    /// [`crate::daemon::metrics::FILE_NAME`] there up to date (OpenMetrics text, written
    /// atomically). `None`: no metrics file.
    pub metrics_dir: Option<PathBuf>,
    /// Frames pooled into one localization at most, the run's own included: the service keeps
    /// the burst median of each run in `stored-frames/` beside the pose and pools those of earlier
    /// hours into the refinement (`crate::frames`). 1 = no pooling, nothing stored.
    pub pool_frames: usize,
    /// A stored frame older than this, hours, is dropped.
    pub pool_max_age_h: f64,
    /// The stored frames take at most this much disk, MB; the oldest go first.
    pub pool_max_disk_mb: f64,
    /// Frames closer together than this, minutes, are one light: the newer replaces the older.
    pub pool_min_spacing_min: f64,
}

impl Default for DaemonConfig {
    fn default() -> Self {
        DaemonConfig {
            socket: PathBuf::from(DEFAULT_SOCKET),
            history_len: crate::store::DEFAULT_HISTORY_LEN,
            relocalize_interval_h: 0.0,
            retry_initial_s: 60.0,
            retry_max_s: 3600.0,
            drift_check_interval_min: 30.0,
            drift_threshold_m: 0.1,
            drift_threshold_deg: 0.3,
            metrics_dir: None,
            pool_frames: 6,
            pool_max_age_h: 72.0,
            pool_max_disk_mb: 200.0,
            pool_min_spacing_min: 45.0,
        }
    }
}

/// Control socket of the installed service.
pub(crate) const DEFAULT_SOCKET: &str = "/run/infraloc/control.sock";

/// Upper bounds of the numeric keys: beyond them a value is a typo or a unit mistake, and some
/// (retries, back-offs, timeouts) would make a run wait for days without a word. Documented in
/// `config/infraloc.toml` and docs/technician.md.
pub(crate) mod limits {
    /// `[camera] frame-count`.
    pub(crate) const FRAME_COUNT: u64 = 100;
    /// `[camera] frame-interval-ms` (one minute).
    pub(crate) const FRAME_INTERVAL_MS: u64 = 60_000;
    /// `[camera] settle-frames`.
    pub(crate) const SETTLE_FRAMES: u64 = 1_000;
    /// `[camera] timeout-ms` (one minute).
    pub(crate) const TIMEOUT_MS: u64 = 60_000;
    /// `[camera] retry-attempts`.
    pub(crate) const RETRY_ATTEMPTS: u64 = 20;
    /// `[camera] retry-backoff-ms`: the doubling back-off is capped at 30 s anyway.
    pub(crate) const RETRY_BACKOFF_MS: u64 = 30_000;
    /// `[camera] exposure-us` (ten seconds).
    pub(crate) const EXPOSURE_US: f64 = 10_000_000.0;
    /// `[gps] window-s`: the prior keeps at most 10 000 fixes, 1000 s at 10 Hz.
    pub(crate) const GPS_WINDOW_S: f64 = 1_000.0;
    /// `[gps] timeout-s` (one hour).
    pub(crate) const GPS_TIMEOUT_S: f64 = 3_600.0;
    /// `[gps] fallback-sigma-m`.
    pub(crate) const SIGMA_M: f64 = 1_000.0;
    /// `[gps] max-hdop`.
    pub(crate) const HDOP: f64 = 100.0;
    /// `[gps] min-fixes`: no more than the prior keeps.
    pub(crate) const MIN_FIXES: u64 = 10_000;
    /// `[gps] reconnect-max-s` (one hour).
    pub(crate) const RECONNECT_S: f64 = 3_600.0;
    /// `[gps] baud`.
    pub(crate) const BAUD: u64 = 4_000_000;
    /// `[map] search-margin-m`.
    pub(crate) const MARGIN_M: f64 = 10_000.0;
    /// `[daemon] history-len`.
    pub(crate) const HISTORY_LEN: u64 = 10_000;
    /// `[daemon] pool-frames`: one run's MI stage holds every pooled frame in memory.
    pub(crate) const POOL_FRAMES: u64 = 32;
    /// `[daemon] pool-max-age-h` (thirty days).
    pub(crate) const POOL_AGE_H: f64 = 720.0;
    /// `[daemon] pool-max-disk-mb` (100 GB).
    pub(crate) const POOL_DISK_MB: f64 = 100_000.0;
    /// `[daemon] pool-min-spacing-min` (one day).
    pub(crate) const POOL_SPACING_MIN: f64 = 1_440.0;
    /// `[output] georef-lut-step-px`: beyond 64 px a cell spans more than a car at the image's
    /// edge, and the table is no lookup table any more.
    pub(crate) const LUT_STEP_PX: u64 = 64;
    /// `[daemon] relocalize-interval-h` (one year).
    pub(crate) const RELOCALIZE_INTERVAL_H: f64 = 8_760.0;
    /// `[daemon] drift-check-interval-min` (one week).
    pub(crate) const DRIFT_INTERVAL_MIN: f64 = 10_080.0;
    /// `[daemon] retry-initial-s` (one day).
    pub(crate) const RETRY_INITIAL_S: f64 = 86_400.0;
    /// `[daemon] retry-max-s` (one week).
    pub(crate) const RETRY_MAX_S: f64 = 604_800.0;
    /// `[daemon] drift-threshold-m`.
    pub(crate) const DRIFT_M: f64 = 100.0;
    /// `[daemon] drift-threshold-deg`.
    pub(crate) const DRIFT_DEG: f64 = 180.0;
}

/// The lower end of a float key's range.
#[derive(Clone, Copy)]
enum Low {
    /// Strictly above.
    Above(f64),
    /// At or above.
    AtLeast(f64),
}
use Low::{Above, AtLeast};

/// Problems found so far, one line each.
#[derive(Default)]
struct Problems(Vec<String>);

impl Problems {
    fn push(&mut self, m: impl Into<String>) {
        self.0.push(m.into());
    }

    /// An integer key within `lo..=hi`.
    fn int(&mut self, key: &str, v: u64, lo: u64, hi: u64) {
        if v < lo || v > hi {
            self.push(format!("{key} = {v} is out of range: use {lo} to {hi}"));
        }
    }

    /// A float key: finite, above (or at least) its lower end, at most `hi`.
    fn float(&mut self, key: &str, v: f64, lo: Low, hi: f64) {
        let (ok_low, lo_text) = match lo {
            Above(l) => (v > l, format!("> {l}")),
            AtLeast(l) => (v >= l, format!(">= {l}")),
        };
        if !v.is_finite() {
            self.push(format!(
                "{key} = {v} is not a finite number: use a value {lo_text} and <= {hi}"
            ));
        } else if !ok_low || v > hi {
            self.push(format!(
                "{key} = {v} is out of range: use a value {lo_text} and <= {hi}"
            ));
        }
    }

    /// A path key, when set, must not be empty (an empty path would resolve to the config's own
    /// directory).
    fn path(&mut self, key: &str, v: Option<&Path>) {
        if v.is_some_and(|p| p.as_os_str().is_empty()) {
            self.push(format!("{key} is empty: give a path"));
        }
    }
}

impl Config {
    /// Parse and validate TOML text ([`Config::validate`]); relative paths stay as written.
    /// `origin` names the source in errors.
    pub fn parse(text: &str, origin: &Path) -> Result<Config> {
        let cfg = Config::parse_unchecked(text, origin)?;
        cfg.validate(origin)?;
        Ok(cfg)
    }

    /// Parse TOML text without [`Config::validate`] (tests of the validation itself).
    pub(crate) fn parse_unchecked(text: &str, origin: &Path) -> Result<Config> {
        toml::from_str(text).map_err(|e| {
            // toml's message spans several lines with a source excerpt; keep one line.
            let msg = e.message().trim().to_string();
            let at = e
                .span()
                .map(|s| {
                    let line = text[..s.start.min(text.len())].matches('\n').count() + 1;
                    format!("line {line}: ")
                })
                .unwrap_or_default();
            Error::config(origin, format!("{at}{msg}"))
        })
    }

    /// Read a config file, validate it ([`Config::validate`]: every key-level problem, exit 78)
    /// and resolve its relative paths against the file's directory. The one way the program
    /// reads its configuration, so no caller can skip the validation. What the config names on
    /// this machine (files, devices, directories) is checked by `crate::preflight`.
    pub fn load(path: &Path) -> Result<Config> {
        let (cfg, problems) = Config::load_with_problems(path)?;
        Error::config_problems(path, problems)?;
        Ok(cfg)
    }

    /// Read a config file and resolve its paths, returning its [`Config::problems`] rather than
    /// failing on them, so that [`crate::preflight`] can add what it finds on the machine and a
    /// technician sees every problem at once. A file that cannot be read or parsed is an error.
    pub(crate) fn load_with_problems(path: &Path) -> Result<(Config, Vec<String>)> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::config(path, e.to_string()))?;
        let mut cfg = Config::parse_unchecked(&text, path)?;
        let problems = cfg.problems();
        let base = path.parent().unwrap_or(Path::new("."));
        cfg.resolve_paths(base);
        Ok((cfg, problems))
    }

    /// Make every relative path absolute against `base`.
    pub(crate) fn resolve_paths(&mut self, base: &Path) {
        // An empty path stays empty, so validation can name it instead of it becoming `base`.
        let fix = |p: &mut PathBuf| {
            if p.is_relative() && !p.as_os_str().is_empty() {
                *p = base.join(&*p);
            }
        };
        self.camera.intrinsics_file.as_mut().map(fix);
        self.camera.frames.as_mut().map(fix);
        self.gps.path.as_mut().map(fix);
        fix(&mut self.map.tiles);
        fix(&mut self.output.pose);
        self.output.report.as_mut().map(fix);
        self.output.overlay.as_mut().map(fix);
        fix(&mut self.daemon.socket);
        self.daemon.metrics_dir.as_mut().map(fix);
        self.init.matcher_path.as_mut().map(fix);
    }

    /// Hard errors a parsed config can still have: missing required combinations, values out of
    /// range or beyond the `limits`. Every problem is reported, each naming its `[section] key`
    /// (one [`Error::Config`] for one problem, [`Error::ConfigList`] for several). Exit 78.
    pub fn validate(&self, origin: &Path) -> Result<()> {
        Error::config_problems(origin, self.problems())
    }

    /// The problems [`Config::validate`] reports, one line each, `[section] key …` first.
    pub(crate) fn problems(&self) -> Vec<String> {
        let mut p = Problems::default();
        self.camera_problems(&mut p);
        self.gps_problems(&mut p);
        self.map_output_problems(&mut p);
        self.daemon_problems(&mut p);
        if self.init.matcher == MatcherKind::MatchFile && self.init.matcher_path.is_none() {
            p.push("[init] matcher = \"match-file\" needs matcher-path");
        }
        if let Err(m) = self.quality.validate() {
            p.push(format!("[quality] {m}"));
        }
        p.0
    }

    fn camera_problems(&self, p: &mut Problems) {
        let c = &self.camera;
        match (&c.intrinsics_file, &c.intrinsics) {
            (None, None) => {
                p.push("[camera]: set intrinsics-file or an inline [camera.intrinsics] table")
            }
            (Some(_), Some(_)) => {
                p.push("[camera]: intrinsics-file and [camera.intrinsics] are both set; keep one")
            }
            (_, Some(cam)) => {
                if let Err(m) = cam.validate() {
                    p.push(format!("[camera.intrinsics] {m}"));
                }
            }
            (Some(_), None) => {}
        }
        p.path("[camera] intrinsics-file", c.intrinsics_file.as_deref());
        p.path("[camera] frames", c.frames.as_deref());
        if c.source == FrameSourceKind::File && c.frames.is_none() {
            p.push("[camera] source = \"file\" needs frames");
        }
        if !c.source.compiled_in() {
            p.push(c.source.missing_backend_problem());
        }
        if c.source == FrameSourceKind::V4l2 && c.device.as_deref().is_none_or(str::is_empty) {
            p.push("[camera] source = \"v4l2\" needs device");
        }
        p.int(
            "[camera] frame-count",
            c.frame_count.into(),
            1,
            limits::FRAME_COUNT,
        );
        p.int(
            "[camera] frame-interval-ms",
            c.frame_interval_ms,
            0,
            limits::FRAME_INTERVAL_MS,
        );
        p.int(
            "[camera] settle-frames",
            c.settle_frames.into(),
            0,
            limits::SETTLE_FRAMES,
        );
        p.int("[camera] timeout-ms", c.timeout_ms, 1, limits::TIMEOUT_MS);
        p.int(
            "[camera] retry-attempts",
            c.retry_attempts.into(),
            1,
            limits::RETRY_ATTEMPTS,
        );
        p.int(
            "[camera] retry-backoff-ms",
            c.retry_backoff_ms,
            0,
            limits::RETRY_BACKOFF_MS,
        );
        let kind = c.source.name();
        if let Some(f) = &c.pixel_format {
            let known = c.source.pixel_formats();
            if !known.contains(&f.as_str()) {
                p.push(if known.is_empty() {
                    format!("[camera] pixel-format is not used with source = \"{kind}\"")
                } else {
                    format!(
                        "[camera] pixel-format = \"{f}\" is not one of {} (source = \"{kind}\")",
                        known.join(", ")
                    )
                });
            }
        }
        if c.resolution.is_some() && c.source != FrameSourceKind::V4l2 {
            p.push(format!(
                "[camera] resolution is for source = \"v4l2\" (use region for aravis), not \"{kind}\""
            ));
        }
        if let Some([w, h]) = c.resolution {
            if w == 0 || h == 0 {
                p.push(format!("[camera] resolution = [{w}, {h}] must be positive"));
            }
        }
        for (key, set) in [
            ("region", c.region.is_some()),
            ("exposure-us", c.exposure_us.is_some()),
            ("gain-db", c.gain_db.is_some()),
        ] {
            if set && c.source != FrameSourceKind::Aravis {
                p.push(format!(
                    "[camera] {key} is for source = \"aravis\", not \"{kind}\""
                ));
            }
        }
        if let Some([_, _, w, h]) = c.region {
            if w == 0 || h == 0 {
                p.push(format!(
                    "[camera] region width and height must be positive, got {w}x{h}"
                ));
            }
        }
        if let Some(e) = c.exposure_us {
            p.float("[camera] exposure-us", e, Above(0.0), limits::EXPOSURE_US);
        }
        if let Some(g) = c.gain_db {
            if !g.is_finite() {
                p.push(format!("[camera] gain-db = {g} is not a finite number"));
            }
        }
    }

    fn gps_problems(&self, p: &mut Problems) {
        let g = &self.gps;
        match g.source {
            GpsSourceKind::NmeaFile if g.path.is_none() => {
                p.push("[gps] source = \"nmea-file\" needs path")
            }
            GpsSourceKind::Serial if g.device.as_deref().is_none_or(str::is_empty) => {
                p.push("[gps] source = \"serial\" needs device")
            }
            GpsSourceKind::Fixed if g.fallback_wgs84.is_none() => {
                p.push("[gps] source = \"fixed\" needs fallback-wgs84")
            }
            _ => {}
        }
        p.path("[gps] path", g.path.as_deref());
        if let Some([lat, lon]) = g.fallback_wgs84 {
            if !(lat.abs() <= 90.0 && lon.abs() <= 180.0) {
                p.push(format!(
                    "[gps] fallback-wgs84 = [{lat}, {lon}] is not a WGS84 position"
                ));
            }
        }
        p.float(
            "[gps] window-s",
            g.window_s,
            Above(0.0),
            limits::GPS_WINDOW_S,
        );
        p.float(
            "[gps] timeout-s",
            g.timeout_s,
            AtLeast(0.0),
            limits::GPS_TIMEOUT_S,
        );
        p.float(
            "[gps] fallback-sigma-m",
            g.fallback_sigma_m,
            Above(0.0),
            limits::SIGMA_M,
        );
        p.float("[gps] max-hdop", g.max_hdop, Above(0.0), limits::HDOP);
        p.int("[gps] min-fixes", g.min_fixes as u64, 0, limits::MIN_FIXES);
        p.float(
            "[gps] reconnect-max-s",
            g.reconnect_max_s,
            Above(0.0),
            limits::RECONNECT_S,
        );
        if g.source == GpsSourceKind::Serial {
            p.int("[gps] baud", g.baud.into(), 1, limits::BAUD);
        }
    }

    fn map_output_problems(&self, p: &mut Problems) {
        p.path("[map] tiles", Some(&self.map.tiles));
        p.float(
            "[map] search-margin-m",
            self.map.search_margin_m,
            AtLeast(0.0),
            limits::MARGIN_M,
        );
        let o = &self.output;
        p.path("[output] pose", Some(&o.pose));
        p.path("[output] report", o.report.as_deref());
        p.path("[output] overlay", o.overlay.as_deref());
        p.int(
            "[output] georef-lut-step-px",
            o.georef_lut_step_px.into(),
            0,
            limits::LUT_STEP_PX,
        );
        p.path("[init] matcher-path", self.init.matcher_path.as_deref());
    }

    fn daemon_problems(&self, p: &mut Problems) {
        let d = &self.daemon;
        p.path("[daemon] socket", Some(&d.socket));
        p.path("[daemon] metrics-dir", d.metrics_dir.as_deref());
        p.int(
            "[daemon] history-len",
            d.history_len as u64,
            1,
            limits::HISTORY_LEN,
        );
        p.float(
            "[daemon] relocalize-interval-h",
            d.relocalize_interval_h,
            AtLeast(0.0),
            limits::RELOCALIZE_INTERVAL_H,
        );
        p.float(
            "[daemon] drift-check-interval-min",
            d.drift_check_interval_min,
            AtLeast(0.0),
            limits::DRIFT_INTERVAL_MIN,
        );
        p.float(
            "[daemon] retry-initial-s",
            d.retry_initial_s,
            Above(0.0),
            limits::RETRY_INITIAL_S,
        );
        p.float(
            "[daemon] retry-max-s",
            d.retry_max_s,
            Above(0.0),
            limits::RETRY_MAX_S,
        );
        p.float(
            "[daemon] drift-threshold-m",
            d.drift_threshold_m,
            Above(0.0),
            limits::DRIFT_M,
        );
        p.float(
            "[daemon] drift-threshold-deg",
            d.drift_threshold_deg,
            Above(0.0),
            limits::DRIFT_DEG,
        );
        p.int(
            "[daemon] pool-frames",
            d.pool_frames as u64,
            1,
            limits::POOL_FRAMES,
        );
        p.float(
            "[daemon] pool-max-age-h",
            d.pool_max_age_h,
            Above(0.0),
            limits::POOL_AGE_H,
        );
        p.float(
            "[daemon] pool-max-disk-mb",
            d.pool_max_disk_mb,
            Above(0.0),
            limits::POOL_DISK_MB,
        );
        p.float(
            "[daemon] pool-min-spacing-min",
            d.pool_min_spacing_min,
            AtLeast(0.0),
            limits::POOL_SPACING_MIN,
        );
    }

    /// Semantic warnings: legal but probably not what was meant.
    pub fn check(&self) -> Vec<String> {
        let mut w = Vec::new();
        if self.refine.is_some() {
            w.push(
                "[refine] is retired and ignored: the smooth estimator is the only local stage; remove the section"
                    .into(),
            );
        }
        if self.quality.retired_jackknife_folds.is_some() {
            w.push(
                "[quality] jackknife-folds is retired and ignored: σ comes from the smooth estimator's information; remove the key"
                    .into(),
            );
        }
        if self.camera.frame_count < 3 {
            w.push(format!(
                "[camera] frame-count = {}: fewer than 3 frames cannot remove traffic by median",
                self.camera.frame_count
            ));
        }
        if self.gps.window_s < 5.0 {
            w.push(format!(
                "[gps] window-s = {}: a short window averages little GPS noise",
                self.gps.window_s
            ));
        }
        if self.gps.source != GpsSourceKind::Fixed && self.gps.fallback_wgs84.is_none() {
            w.push("[gps] no fallback-wgs84: without a fix the node cannot localize".into());
        }
        if self.init.matcher == MatcherKind::DenseSweep {
            if let Some(p) = &self.init.matcher_path {
                w.push(format!(
                    "[init] matcher-path {} is unused: matcher = \"dense-sweep\" reads no file",
                    p.display()
                ));
            }
        }
        if self.map.search_margin_m > 500.0 {
            w.push(format!(
                "[map] search-margin-m = {} m is larger than any tile is likely to be",
                self.map.search_margin_m
            ));
        }
        let d = &self.daemon;
        if d.retry_max_s < d.retry_initial_s {
            w.push(format!(
                "[daemon] retry-max-s = {} is below retry-initial-s = {}: retries wait retry-initial-s",
                d.retry_max_s, d.retry_initial_s
            ));
        }
        if d.pool_frames > 1 && d.pool_max_age_h * 60.0 < d.pool_min_spacing_min {
            w.push(format!(
                "[daemon] pool-max-age-h = {} is shorter than pool-min-spacing-min = {}: no stored frame is ever pooled",
                d.pool_max_age_h, d.pool_min_spacing_min
            ));
        }
        if d.drift_check_interval_min > 0.0 && d.drift_threshold_m >= 0.5 {
            w.push(format!(
                "[daemon] drift-threshold-m = {} reaches the drift search's ±0.5 m box: a moved camera shows as a gate failure",
                d.drift_threshold_m
            ));
        }
        w
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_key_is_a_config_error_naming_the_key() {
        let e = Config::parse("[camera]\nframe-cont = 3\n", Path::new("x.toml")).unwrap_err();
        assert_eq!(e.exit_code(), crate::error::EXIT_CONFIG);
        let s = e.to_string();
        assert!(s.contains("frame-cont") && s.contains("line 2"), "{s}");
        assert!(!s.contains('\n'));
    }

    #[test]
    fn a_source_this_build_lacks_is_a_config_error_saying_how_to_get_one() {
        let t = "[camera]\nintrinsics-file = \"c.yaml\"\nsource = \"v4l2\"\n\
                 device = \"/dev/video0\"\n[gps]\nsource = \"fixed\"\n\
                 fallback-wgs84 = [42.0, -83.0]\n";
        for (kind, feature) in [
            (FrameSourceKind::V4l2, "v4l"),
            (FrameSourceKind::Aravis, "aravis"),
        ] {
            let m = kind.missing_backend_problem();
            let key = format!("[camera] source = \"{}\"", kind.name());
            assert!(m.starts_with(&key), "{m}");
            assert!(m.contains(&format!("--features {feature}")), "{m}");
            assert!(!m.contains('\n'));
            let text = t.replace("\"v4l2\"", &format!("\"{}\"", kind.name()));
            match Config::parse(&text, Path::new("x.toml")) {
                Ok(_) => assert!(kind.compiled_in(), "{key} accepted without its backend"),
                Err(e) => {
                    assert!(!kind.compiled_in(), "{e}");
                    assert_eq!(e.exit_code(), crate::error::EXIT_CONFIG);
                    assert_eq!(e.to_string(), format!("config x.toml: {m}"));
                }
            }
        }
        assert_eq!(
            FrameSourceKind::V4l2.compiled_in(),
            cfg!(feature = "v4l"),
            "the v4l2 source follows the `v4l` feature"
        );
    }

    #[test]
    fn inline_intrinsics_parse() {
        let t = r#"
[camera]
frames = "frames"
[camera.intrinsics]
model = "mei"
width = 640
height = 480
fx = 300.0
fy = 300.0
cx = 320.0
cy = 240.0
xi = 1.1
k1 = -0.1
[gps]
source = "fixed"
fallback-wgs84 = [42.0, -83.0]
"#;
        let c = Config::parse(t, Path::new("x.toml")).unwrap();
        c.validate(Path::new("x.toml")).unwrap();
        assert!(matches!(c.camera.intrinsics, Some(Camera::Mei(ref m)) if m.xi == 1.1));
        // Unknown key inside the inline camera table is rejected too.
        let bad = t.replace("k1 = -0.1", "k9 = -0.1");
        assert!(Config::parse(&bad, Path::new("x.toml")).is_err());
        // Unusable values are a configuration error naming the parameter.
        let bad = t.replace("fx = 300.0", "fx = -300.0");
        let e = Config::parse(&bad, Path::new("x.toml")).unwrap_err();
        assert_eq!(e.exit_code(), crate::error::EXIT_CONFIG);
        assert!(
            e.to_string().contains("[camera.intrinsics] fx = -300"),
            "{e}"
        );
    }

    #[test]
    fn camera_source_keys_parse_and_validate() {
        let base = "[camera]\nintrinsics-file = \"c.yaml\"\n";
        let gps = "[gps]\nsource = \"fixed\"\nfallback-wgs84 = [42.0, -83.0]\n";
        let ok = |extra: &str| {
            let t = format!("{base}{extra}{gps}");
            Config::parse(&t, Path::new("x.toml"))
        };
        let aravis = ok(
            "source = \"aravis\"\ndevice = \"Basler-123\"\npixel-format = \"BayerRG8\"\n\
                    region = [8, 4, 640, 480]\nexposure-us = 2500.0\ngain-db = 6.0\n\
                    retry-attempts = 5\nretry-backoff-ms = 200\n",
        );
        // A build without a capture backend says so, as a config error naming the feature.
        let built_without = |r: Result<Config>, feature: &str| {
            let e = r.unwrap_err();
            assert_eq!(e.exit_code(), crate::error::EXIT_CONFIG);
            assert!(
                e.to_string().contains(&format!("--features {feature}")),
                "{e}"
            );
        };
        if cfg!(feature = "aravis") {
            let c = aravis.unwrap();
            assert_eq!(c.camera.region, Some([8, 4, 640, 480]));
            assert_eq!(c.camera.retry_attempts, 5);
        } else {
            built_without(aravis, "aravis");
        }
        let v4l2 = ok(
            "source = \"v4l2\"\ndevice = \"/dev/video0\"\npixel-format = \"YUYV\"\n\
                    resolution = [1280, 720]\n",
        );
        if cfg!(feature = "v4l") {
            assert_eq!(v4l2.unwrap().camera.resolution, Some([1280, 720]));
        } else {
            built_without(v4l2, "v4l");
        }

        // Each mistake is a config error (exit 78) naming the key.
        for (extra, key) in [
            (
                "source = \"v4l2\"\ndevice = \"/dev/video0\"\npixel-format = \"Mono8\"\n",
                "pixel-format = \"Mono8\"",
            ),
            (
                "source = \"aravis\"\npixel-format = \"YUYV\"\n",
                "pixel-format = \"YUYV\"",
            ),
            (
                "source = \"v4l2\"\ndevice = \"/dev/video0\"\nregion = [0, 0, 8, 8]\n",
                "region",
            ),
            (
                "source = \"aravis\"\nresolution = [640, 480]\n",
                "resolution",
            ),
            ("source = \"aravis\"\nexposure-us = -1.0\n", "exposure-us"),
            ("source = \"aravis\"\nregion = [0, 0, 0, 8]\n", "region"),
            ("frames = \"f\"\nretry-attempts = 0\n", "retry-attempts"),
            ("frames = \"f\"\ntimeout-ms = 0\n", "timeout-ms"),
            ("frames = \"f\"\ngain-db = 3.0\n", "gain-db"),
        ] {
            let e = ok(extra).unwrap_err();
            assert_eq!(e.exit_code(), crate::error::EXIT_CONFIG);
            // Without the backend the source itself is the first mistake.
            let named = if extra.contains("aravis") && !cfg!(feature = "aravis") {
                "--features aravis"
            } else if extra.contains("v4l2") && !cfg!(feature = "v4l") {
                "--features v4l"
            } else {
                key
            };
            assert!(e.to_string().contains(named), "{extra}: {e}");
        }
    }

    #[test]
    fn missing_intrinsics_fails_validation() {
        let e = Config::parse("[camera]\nframes = \"f\"\n", Path::new("x.toml")).unwrap_err();
        assert!(e.to_string().contains("intrinsics"));
    }
}
