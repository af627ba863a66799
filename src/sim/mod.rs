//! Scene simulator: a seeded intersection world, its LiDAR and satellite map layers, fisheye
//! frames ray-cast from a true pose, a noisy GPS log and surveyed control points — everything
//! `infraloc simulate` writes (docs/interfaces.md, "Scene directory"), generated in memory. Pure: no files, no clock.
//!
//! The three ground-seeing sensors share one world ([`world`]) but see it through different
//! physics ([`appearance`]): that is the modality gap every accuracy number is measured across.
//! See `docs/simulator.md`.

pub(crate) mod appearance;
pub(crate) mod calibrated;
pub mod checkerboard;
pub mod day;
pub mod error;
pub mod gantry;
pub(crate) mod gps;
pub(crate) mod layers;
pub(crate) mod noise;
pub(crate) mod render;
pub(crate) mod shoot;
pub(crate) mod solids;

pub(crate) mod world;

use crate::camera::{Camera, CameraModel, Equidistant, Mei};
use crate::error::Result;
use crate::map::{ControlPoint, Crs, GeoGrid, Raster, Tile};
use crate::pose::CamFromMap;
use appearance::Appearance;
use error::SimError;
use nalgebra::{Point3, Vector3};
use noise::mix64;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use render::{Light, Sensor, View};
use serde::{Deserialize, Serialize};
use shoot::{day_captures, frame_gains, traffic_counts, Burst, Shoot};
use solids::Solid;
use std::f64::consts::{PI, TAU};
use world::World;

/// Map CRS of simulated scenes: WGS84 / UTM 17N (Michigan, where the seed paper's data is from).
pub(crate) const SIM_EPSG: u32 = 32617;
/// Nominal site: UTM 17N coordinates near Ann Arbor, MI (42.28 N, 83.74 W).
const SITE_UTM: [f64; 2] = [274_069.0, 4_684_501.0];
/// The site is moved by up to this much per seed, metres.
const SITE_JITTER: f64 = 3000.0;
/// LiDAR tile side, metres.
pub(crate) const TILE_SIZE_M: f64 = 120.0;
/// Map resolution, metres per pixel.
pub(crate) const MAP_RES: f64 = 0.1;
/// Satellite tile margin beyond the LiDAR tile on each side, metres.
const SAT_MARGIN_M: f64 = 1.0;
/// Geoid separation reported by the receiver (EGM96 near Ann Arbor), metres.
const GEOID_SEP: f64 = -34.5;
/// Frame spacing of the simulated capture, seconds.
const FRAME_DT: f64 = 1.0;
/// Lens field of view, degrees.
const LENS_FOV_DEG: f64 = 185.0;
/// Mei mirror parameter of the simulated lens and the radial terms that make it match an
/// equidistant 185° lens to < 1 px (least-squares fit over 0–92.5°).
const MEI_XI: f64 = 1.2;
/// Mei γ per equidistant focal length (γ ≈ f·(1+ξ), refined by the fit).
const MEI_GAMMA_PER_F: f64 = 2.196_137;
/// Mei k1 of the fit.
const MEI_K1: f64 = -0.269_52;
/// Mei k2 of the fit.
const MEI_K2: f64 = 0.094_65;
/// Largest angle of a control point from the optical axis, degrees (grazing points are useless).
const CONTROL_MAX_THETA_DEG: f64 = 80.0;

/// Image size and optics.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Preset {
    /// 1024×1024, f ≈ 300 px: fast, for tests.
    Small,
    /// 2448×2048 Sony IMX264 (3.45 µm) with a Fujinon FE185C057HA-class 185° lens, f ≈ 540 px.
    #[serde(rename = "5mp")]
    FiveMp,
    /// A roadside gantry 6–9 m up (docs/simulator.md, "Gantry preset"): `small`'s fisheye plus a
    /// 1280×800 perspective camera 20–30° below the horizontal, a 64-ring LiDAR sweep from the
    /// same pole, a low sun and the long shadows of the pole, beam and signs.
    Gantry,
}

/// How hard the scene is for the localizer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Difficulty {
    /// Level camera, good GPS (σ ≈ 2 m), exact intrinsics, light traffic, sunny.
    Easy,
    /// Roll/pitch ±3°, GPS σ ≈ 5 m, calibrated (not exact) intrinsics, dense traffic, noisy sensor.
    Hard,
}

/// Lens model of the simulated camera.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Lens {
    /// Mei / OpenCV omnidir (what the product calibrates with).
    Mei,
    /// Equidistant / OpenCV fisheye (what the seed paper's simulator used).
    Equidistant,
}

/// How a `hard` scene's given intrinsics (camera.yaml) are made; `easy` hands over the true ones.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum GivenIntrinsics {
    /// The product's own calibrator run on rendered checkerboard views of the true camera
    /// (`calibrated::calibrated_camera`), stating the fit's σ: the error a real install has.
    #[default]
    Calibrated,
    /// The true intrinsics with a drawn focal (±0.15–0.3 %) and principal-point (±1–2 px)
    /// offset, stating the spread they are drawn from (`hard` before the calibrator existed).
    Offset,
}

/// What truth.json files written before [`Settings::intrinsics`] existed had.
fn offset() -> GivenIntrinsics {
    GivenIntrinsics::Offset
}

/// A scene captured once, as truth.json files without `times` were.
fn one() -> u32 {
    1
}

/// `times` is left out of truth.json when 1, so a one-capture scene's file is what it was.
fn is_one(n: &u32) -> bool {
    *n == 1
}

/// `low_sun` is left out of truth.json when false.
fn is_false(b: &bool) -> bool {
    !*b
}

/// Generator settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub struct Settings {
    /// Master seed.
    pub seed: u64,
    /// Image preset.
    pub preset: Preset,
    /// Difficulty.
    pub difficulty: Difficulty,
    /// Lens model.
    pub lens: Lens,
    /// Number of frames.
    pub frames: u32,
    /// How `hard`'s given intrinsics are made (ignored by `easy`).
    #[serde(default = "offset")]
    pub intrinsics: GivenIntrinsics,
    /// Times of day the scene is captured at, each a burst of `frames` (module [`day`]); 1 with
    /// `low_sun` off is the single capture of a drawn sun.
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub times: u32,
    /// The sun at most 25° up at every time (a day near the winter solstice).
    #[serde(default, skip_serializing_if = "is_false")]
    pub low_sun: bool,
}

/// A control point with its true image position.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TruthPoint {
    /// Identifier (`a<approach>-<marking>-<vertex>`; empty when a hand-written file has none).
    #[serde(default)]
    pub id: String,
    /// Map coordinates (CRS of the scene).
    pub map: [f64; 3],
    /// Pixel (u, v), OpenCV convention.
    pub pixel: [f64; 2],
}

/// Acquisition details recorded in truth.json (what made this scene what it is).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Acquisition {
    /// Camera sun azimuth/elevation (deg) and whether overcast.
    pub camera_sun_az_el_deg: [f64; 2],
    /// Camera sky is overcast (no direct sun).
    pub camera_overcast: bool,
    /// Satellite sun azimuth/elevation, degrees.
    pub satellite_sun_az_el_deg: [f64; 2],
    /// Satellite off-nadir angle, degrees.
    pub satellite_off_nadir_deg: f64,
    /// Satellite misregistration against the LiDAR layers (east, north), metres.
    pub satellite_shift_m: [f64; 2],
    /// Satellite JPEG quality.
    pub satellite_jpeg_quality: u8,
    /// GPS bias σ and noise σ per axis, metres.
    pub gps_sigma_bias_noise_m: [f64; 2],
    /// Camera height above the ground below it, metres.
    pub camera_height_above_ground_m: f64,
    /// Number of approaches of the intersection.
    pub approaches: usize,
    /// Moving vehicles and pedestrians per frame.
    pub traffic_vehicles_pedestrians: [usize; 2],
    /// The gantry preset's sensors (absent in the other presets).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gantry: Option<GantryAcquisition>,
    /// The captures of a day (`simulate --times K` or `--low-sun`), in time order; the first is
    /// the one the fields above describe. Empty for a single capture of a drawn sun.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub times: Vec<TimeRecord>,
}

/// What truth.json records of one capture of a day.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TimeRecord {
    /// UTC time of the capture's first frame, as pose files write it.
    pub utc: String,
    /// Sun azimuth (clockwise from north) and elevation, degrees.
    pub sun_az_el_deg: [f64; 2],
    /// The sky is overcast (no direct sun, no shadows).
    pub overcast: bool,
    /// Moving vehicles and pedestrians of this capture.
    pub traffic_vehicles_pedestrians: [usize; 2],
    /// The capture's frames, relative to the scene directory ([`time_dir`]).
    pub frames: String,
    /// The burst's temporal median, what a node keeps of a run ([`time_median`]).
    pub median: String,
}

/// Directory of capture `t`'s frames in a scene directory.
pub fn time_dir(t: usize) -> String {
    format!("times/{t:02}")
}

/// The temporal median of capture `t`'s burst in a scene directory.
pub fn time_median(t: usize) -> String {
    format!("times/{t:02}.png")
}

/// One capture of a day, rendered.
#[derive(Debug, Clone)]
pub struct Capture {
    /// UTC time of the first frame.
    pub start: gps::UtcStart,
    /// Sun azimuth (clockwise from north) and elevation, degrees.
    pub sun_az_el_deg: [f64; 2],
    /// Overcast sky.
    pub overcast: bool,
    /// Moving vehicles and pedestrians.
    pub traffic: [usize; 2],
    /// Fisheye frames, 8-bit gray, row-major.
    pub frames: Vec<Vec<u8>>,
    /// The gantry preset's perspective frames (empty in the other presets).
    pub perspective: Vec<Vec<u8>>,
    /// The gantry preset's LiDAR sweeps, one per frame (empty in the other presets).
    pub sweeps: Vec<Vec<gantry::SweepPoint>>,
}

/// What the gantry preset's truth.json records of its sensors.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GantryAcquisition {
    /// The perspective camera's view direction (clockwise from north) and its pitch below the
    /// horizontal, degrees.
    pub perspective_heading_pitch_deg: [f64; 2],
    /// The LiDAR's height above the ground below it, metres.
    pub lidar_height_above_ground_m: f64,
    /// LiDAR rings and columns per sweep.
    pub lidar_rings_columns: [usize; 2],
    /// Elevation of the top and bottom ring in the LiDAR frame, degrees.
    pub lidar_ring_elevations_deg: [f64; 2],
    /// Returns per sweep (one per frame).
    pub sweep_points: Vec<usize>,
    /// Returns of the first sweep that project into the perspective image at the truth.
    pub sweep_points_in_view: usize,
}

/// The gantry preset's perspective camera and LiDAR, generated with the scene.
#[derive(Debug, Clone)]
pub struct GantryScene {
    /// The gantry, its sensors and their poses (world's local frame).
    pub rig: gantry::Rig,
    /// Perspective camera's true pose in the map CRS.
    pub pose: CamFromMap,
    /// Perspective frames, 8-bit gray, row-major (one per fisheye frame, taken at the same time).
    pub frames: Vec<Vec<u8>>,
    /// One LiDAR sweep per frame, in the LiDAR frame.
    pub sweeps: Vec<Vec<gantry::SweepPoint>>,
}

/// A generated scene, in memory.
#[derive(Debug, Clone)]
pub struct Scene {
    /// Settings it was generated with.
    pub settings: Settings,
    /// Map CRS.
    pub crs: Crs,
    /// Map position of the world's local origin (intersection centre).
    pub origin: [f64; 2],
    /// The world (local coordinates).
    pub world: World,
    /// True intrinsics.
    pub camera_true: Camera,
    /// Intrinsics handed to the localizer (perturbed in `hard`).
    pub camera_given: Camera,
    /// The given intrinsics' stated uncertainty (`hard`: the spread their errors are drawn
    /// from, as a calibration report would state it; `easy`: none, they are exact).
    pub camera_sigma: Option<crate::camera::import::IntrinsicsSigma>,
    /// True pose in the map CRS.
    pub pose: CamFromMap,
    /// Map tile (satellite, reflectivity, height, control points).
    pub tile: Tile,
    /// Fisheye frames, 8-bit gray, row-major.
    pub frames: Vec<Vec<u8>>,
    /// NMEA log text.
    pub nmea: String,
    /// True camera position in WGS84 (lat, lon).
    pub gps_truth_wgs84: [f64; 2],
    /// Visible control points with true pixels.
    pub control_points: Vec<TruthPoint>,
    /// Acquisition details.
    pub acquisition: Acquisition,
    /// UTC start of the GPS log (also the capture time).
    pub start: gps::UtcStart,
    /// The gantry preset's perspective camera and LiDAR sweeps.
    pub gantry: Option<GantryScene>,
    /// The captures of a day, the first the one of `frames` and `gantry` (empty for a single
    /// capture of a drawn sun).
    pub times: Vec<Capture>,
}

/// The scene's map origin: the nominal site moved by up to [`SITE_JITTER`].
fn site_origin(rng: &mut ChaCha8Rng) -> [f64; 2] {
    [
        (SITE_UTM[0] + rng.random_range(-SITE_JITTER..SITE_JITTER)).round(),
        (SITE_UTM[1] + rng.random_range(-SITE_JITTER..SITE_JITTER)).round(),
    ]
}

/// The true intrinsics [`generate`] gives a scene of these settings (the same draws, without
/// building the scene): what `simulate --checkerboard` renders boards with.
pub fn scene_true_camera(settings: &Settings) -> Camera {
    let mut rng = ChaCha8Rng::seed_from_u64(mix64(settings.seed));
    site_origin(&mut rng);
    true_camera(&mut rng, settings.preset, settings.lens)
}

/// True intrinsics for a preset and lens, with per-unit manufacturing jitter.
fn true_camera(rng: &mut ChaCha8Rng, preset: Preset, lens: Lens) -> Camera {
    let (w, h, f) = match preset {
        Preset::Small | Preset::Gantry => (1024u32, 1024u32, 300.0),
        Preset::FiveMp => (2448, 2048, 540.0),
    };
    let f = f * rng.random_range(0.99..1.01);
    let cx = (w as f64 - 1.0) / 2.0 + rng.random_range(-6.0..6.0);
    let cy = (h as f64 - 1.0) / 2.0 + rng.random_range(-6.0..6.0);
    let aspect = 1.0 + rng.random_range(-8e-4..8e-4);
    match lens {
        Lens::Mei => Camera::Mei(Mei {
            width: w,
            height: h,
            fx: f * MEI_GAMMA_PER_F,
            fy: f * MEI_GAMMA_PER_F * aspect,
            cx,
            cy,
            skew: 0.0,
            xi: MEI_XI,
            k1: MEI_K1 * rng.random_range(0.98..1.02),
            k2: MEI_K2 * rng.random_range(0.98..1.02),
            p1: rng.random_range(-2e-4..2e-4),
            p2: rng.random_range(-2e-4..2e-4),
            fov_deg: Some(LENS_FOV_DEG),
        }),
        Lens::Equidistant => Camera::Equidistant(Equidistant {
            width: w,
            height: h,
            fx: f,
            fy: f * aspect,
            cx,
            cy,
            alpha: 0.0,
            k1: rng.random_range(-0.015..-0.005),
            k2: rng.random_range(0.0..0.002),
            k3: rng.random_range(-4e-4..0.0),
            k4: rng.random_range(0.0..4e-5),
            fov_deg: Some(LENS_FOV_DEG),
            cache: Default::default(),
        }),
    }
}

/// The intrinsics a slightly wrong calibration would give: focal ±0.15–0.3 %, principal point
/// ±1–2 px.
/// `hard`'s focal scale error: ± this range (relative), uniform in magnitude, random sign.
const HARD_FOCAL_ERROR: (f64, f64) = (0.0015, 0.003);
/// `hard`'s principal-point error per coordinate: ± this range (px).
const HARD_PRINCIPAL_POINT_ERROR: (f64, f64) = (1.0, 2.0);

/// Mean square of a magnitude uniform in `[a, b)` with a random sign.
#[cfg(test)]
const fn rms_uniform(a: f64, b: f64) -> f64 {
    // E[x²] = (b³ − a³) / (3 (b − a)); no const sqrt, so the caller's value is checked in a test.
    (b * b * b - a * a * a) / (3.0 * (b - a))
}

/// The 1σ `hard` states for its given intrinsics: the RMS of the errors [`perturbed_camera`] draws.
pub(crate) const HARD_INTRINSICS_SIGMA: crate::camera::import::IntrinsicsSigma =
    crate::camera::import::IntrinsicsSigma {
        focal_rel: 0.002_291_3,
        principal_point_px: 1.527_5,
    };

fn perturbed_camera(rng: &mut ChaCha8Rng, cam: &Camera) -> Camera {
    let sign = |rng: &mut ChaCha8Rng| if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    let fs = 1.0 + sign(rng) * rng.random_range(HARD_FOCAL_ERROR.0..HARD_FOCAL_ERROR.1);
    let (a, b) = HARD_PRINCIPAL_POINT_ERROR;
    let dx = sign(rng) * rng.random_range(a..b);
    let dy = sign(rng) * rng.random_range(a..b);
    let mut c = cam.clone();
    match &mut c {
        Camera::Mei(m) => {
            m.fx *= fs;
            m.fy *= fs;
            m.cx += dx;
            m.cy += dy;
        }
        Camera::Equidistant(m) => {
            m.fx *= fs;
            m.fy *= fs;
            m.cx += dx;
            m.cy += dy;
            m.cache = Default::default();
        }
    }
    c
}

/// A moving road user: its path and speed; its shape is regenerated from `shape_seed` each frame.
#[derive(Debug, Clone, Copy)]
struct Mover {
    approach: usize,
    /// Lateral position (vehicles: lane centre; pedestrians on sidewalks: fixed).
    l: f64,
    s: f64,
    /// Signed speed along s (vehicles, sidewalk pedestrians) or along l (crosswalk pedestrians).
    v: f64,
    along_l: bool,
    range: (f64, f64),
    vehicle: bool,
    shape_seed: u64,
}

fn traffic(w: &World, rng: &mut ChaCha8Rng, vehicles: usize, pedestrians: usize) -> Vec<Mover> {
    let k = w.approaches.len();
    let mut out = Vec::new();
    for _ in 0..vehicles {
        let i = rng.random_range(0..k);
        let a = &w.approaches[i];
        let inbound = rng.random_bool(0.5);
        let lanes = if inbound { a.lanes_in } else { a.lanes_out };
        let lane = rng.random_range(0..lanes) as f64;
        let l = (lane + 0.5) * a.lane_w * if inbound { 1.0 } else { -1.0 };
        let speed = rng.random_range(4.0..14.0);
        out.push(Mover {
            approach: i,
            l,
            // Denser near the junction, where queues form and the camera looks.
            s: a.s_cw - 4.0 + 70.0 * rng.random::<f64>().powi(2),
            v: if inbound { -speed } else { speed },
            along_l: false,
            range: (a.s_cw - 6.0, 75.0),
            vehicle: true,
            shape_seed: rng.random(),
        });
    }
    for _ in 0..pedestrians {
        let i = rng.random_range(0..k);
        let a = &w.approaches[i];
        let speed = rng.random_range(0.9..1.7) * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
        let m = if a.crosswalk && rng.random_bool(0.5) {
            Mover {
                approach: i,
                l: rng.random_range(-a.w_out..a.w_in),
                s: a.s_cw + rng.random_range(0.5..2.5),
                v: speed,
                along_l: true,
                range: (-a.w_out - 2.0, a.w_in + 2.0),
                vehicle: false,
                shape_seed: rng.random(),
            }
        } else {
            let side = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            let corner = if side > 0.0 {
                w.corners[i]
            } else {
                w.corners[(i + k - 1) % k]
            };
            let base = if side > 0.0 { a.w_in } else { a.w_out };
            Mover {
                approach: i,
                l: side * (base + world::CURB_W + corner.lawn_w + 0.5 * corner.sidewalk_w),
                s: rng.random_range(a.s_cw + 4.0..50.0),
                v: speed,
                along_l: false,
                range: (a.s_cw + 3.0, 60.0),
                vehicle: false,
                shape_seed: rng.random(),
            }
        };
        out.push(m);
    }
    out
}

fn movers_at(w: &World, movers: &[Mover], frame: u32) -> Vec<Solid> {
    let mut out = Vec::new();
    for m in movers {
        let a = &w.approaches[m.approach];
        let span = m.range.1 - m.range.0;
        let moved = m.v * FRAME_DT * frame as f64;
        let (s, l) = if m.along_l {
            (m.s, m.range.0 + (m.l + moved - m.range.0).rem_euclid(span))
        } else {
            (m.range.0 + (m.s + moved - m.range.0).rem_euclid(span), m.l)
        };
        let (x, y) = a.point(s, l);
        let z = w.height(x, y);
        let mut r = ChaCha8Rng::seed_from_u64(m.shape_seed);
        if m.vehicle {
            let yaw = a.angle + if m.v < 0.0 { PI } else { 0.0 };
            out.extend(world::vehicle(&mut r, x, y, z, yaw));
        } else {
            out.push(world::pedestrian(&mut r, x, y, z));
        }
    }
    out
}

/// `--frames` and `--times` within their bounds, else one line naming the flag.
fn check_counts(settings: &Settings) -> Result<()> {
    if settings.frames == 0 || settings.frames > 1000 {
        return Err(SimError::Count {
            flag: "--frames",
            value: settings.frames,
            max: 1000,
        }
        .into());
    }
    if settings.times == 0 || settings.times > day::MAX_TIMES {
        return Err(SimError::Count {
            flag: "--times",
            value: settings.times,
            max: day::MAX_TIMES,
        }
        .into());
    }
    Ok(())
}

/// truth.json's record of each capture of the day.
fn time_records(day: &[Capture]) -> Vec<TimeRecord> {
    day.iter()
        .enumerate()
        .map(|(t, c)| TimeRecord {
            utc: utc_string(&c.start),
            sun_az_el_deg: c.sun_az_el_deg,
            overcast: c.overcast,
            traffic_vehicles_pedestrians: c.traffic,
            frames: time_dir(t),
            median: time_median(t),
        })
        .collect()
}

/// Generate a scene.
pub fn generate(settings: &Settings) -> Result<Scene> {
    check_counts(settings)?;
    let hard = settings.difficulty == Difficulty::Hard;
    let mut rng = ChaCha8Rng::seed_from_u64(mix64(settings.seed));
    let mut world = World::generate(mix64(settings.seed ^ 0x5EED));
    let crs = Crs::Epsg(SIM_EPSG);
    let origin = site_origin(&mut rng);

    // Camera and true pose.
    let camera_true = true_camera(&mut rng, settings.preset, settings.lens);
    let camera_given = if hard {
        perturbed_camera(&mut rng, &camera_true)
    } else {
        camera_true.clone()
    };
    // The calibrated choice replaces the intrinsics after the offset's draws, so the rest of the
    // scene (pose, world, frames) is the same as with the offset: only the intrinsics differ.
    let (camera_given, camera_sigma) = match settings.intrinsics {
        _ if !hard => (camera_given, None),
        GivenIntrinsics::Offset => (camera_given, Some(HARD_INTRINSICS_SIGMA)),
        GivenIntrinsics::Calibrated => {
            let (c, sigma) =
                calibrated::calibrated_camera(&camera_true, mix64(settings.seed ^ 0xCA1B_0A2D))
                    .map_err(|reason| SimError::Intrinsics { reason })?;
            (c, Some(sigma))
        }
    };
    let gantry = settings.preset == Preset::Gantry;
    let (pose_local, pose, above) = true_pose(&mut rng, &mut world, hard, origin, gantry);
    // The gantry stands in the world before anything is rendered: its shadows fall on every
    // image, and the satellite sees it.
    let rig = gantry.then(|| gantry::rig(&world, &pose_local, settings.seed));
    if let Some(r) = &rig {
        world.statics.extend_from_slice(&r.solids);
    }

    // Map layers.
    let look = Appearance::new(world.seed);
    let half = TILE_SIZE_M / 2.0;
    let n = (TILE_SIZE_M / MAP_RES).round() as usize;
    let grid = GeoGrid {
        crs,
        x0: origin[0] - half,
        y0: origin[1] + half,
        res: MAP_RES,
        width: n,
        height: n,
    };
    let lidar = layers::lidar(&world, &look, &grid, origin, if hard { 0.03 } else { 0.02 });
    let sat = satellite_layer(&mut rng, &world, &look, origin, crs)?;

    // Fisheye frames.
    let overcast = hard && rng.random_bool(0.25);
    let cam_sun = (rng.random_range(0.0..360.0), rng.random_range(18.0..65.0));
    // The gantry's sun is its rig's: low, behind the perspective camera, never overcast.
    let (overcast, cam_sun) = match &rig {
        Some(r) => (false, (r.sun_az_el_deg[0], r.sun_az_el_deg[1])),
        None => (overcast, cam_sun),
    };
    let mut statics = world.statics.clone();
    statics.extend_from_slice(&world.camera_parked);
    let (nv, np) = traffic_counts(&mut rng, hard);
    let movers = traffic(&world, &mut rng, nv, np);
    let gains = frame_gains(&mut rng, settings.frames);
    let shoot = Shoot {
        world: &world,
        look: &look,
        statics: &statics,
        sensor: sensor(hard),
        camera: &camera_true,
        pose_local: &pose_local,
        rig: rig.as_ref(),
    };
    let day = day_captures(settings, &shoot, crs, origin, (&movers, &gains))?;
    let first = match day.first() {
        Some(c) => Burst {
            frames: c.frames.clone(),
            perspective: c.perspective.clone(),
            sweeps: c.sweeps.clone(),
        },
        None => shoot.burst(cam_sun, overcast, (&movers, &gains), 0),
    };
    let (cam_sun, overcast, traffic_counts) = match day.first() {
        Some(c) => (
            (c.sun_az_el_deg[0], c.sun_az_el_deg[1]),
            c.overcast,
            c.traffic,
        ),
        None => (cam_sun, overcast, [nv, np]),
    };
    let gantry_scene = rig.map(|r| gantry_scene(r, first.perspective, first.sweeps, origin));
    let frames = first.frames;

    let gps = gps_log(&mut rng, hard, &pose, crs, day.first().map(|c| c.start))?;

    let (control_points, tile_points) =
        control_points(&world, &statics, origin, &pose, &pose_local, &camera_true);

    let tile = Tile {
        id: format!("sim-{:04}", settings.seed % 10_000),
        satellite: Some(sat.image),
        reflectivity: lidar.reflectivity,
        height: lidar.height,
        control_points: tile_points,
    };
    let acquisition = Acquisition {
        camera_sun_az_el_deg: [cam_sun.0, cam_sun.1],
        camera_overcast: overcast,
        satellite_sun_az_el_deg: [sat.sun_az_el.0, sat.sun_az_el.1],
        satellite_off_nadir_deg: sat.off_nadir_deg,
        satellite_shift_m: sat.shot.shift,
        satellite_jpeg_quality: sat.shot.jpeg_quality,
        gps_sigma_bias_noise_m: gps.sigma_bias_noise_m,
        camera_height_above_ground_m: above,
        approaches: world.approaches.len(),
        traffic_vehicles_pedestrians: traffic_counts,
        gantry: gantry_scene.as_ref().map(|g| g.acquisition(&world)),
        times: time_records(&day),
    };
    Ok(Scene {
        settings: *settings,
        crs,
        origin,
        world,
        camera_true,
        camera_given,
        camera_sigma,
        pose,
        tile,
        frames,
        nmea: gps.nmea,
        gps_truth_wgs84: gps.truth_wgs84,
        control_points,
        acquisition,
        start: gps.start,
        gantry: gantry_scene,
        times: day,
    })
}

/// The gantry scene of `rig`: its true pose in the map and the first capture's perspective
/// frames and sweeps.
fn gantry_scene(
    rig: gantry::Rig,
    frames: Vec<Vec<u8>>,
    sweeps: Vec<Vec<gantry::SweepPoint>>,
    origin: [f64; 2],
) -> GantryScene {
    let c = rig.pose_local.center();
    let pose = CamFromMap::from_center(
        rig.pose_local.rotation,
        &Point3::new(c.x + origin[0], c.y + origin[1], c.z),
    );
    GantryScene {
        rig,
        pose,
        frames,
        sweeps,
    }
}

impl GantryScene {
    /// The returns of `sweep` that project into the perspective image at the true pose.
    pub fn in_view(&self, sweep: &[gantry::SweepPoint]) -> usize {
        let pose = self.rig.pose_in_lidar();
        let cam = &self.rig.camera;
        sweep
            .iter()
            .filter(|p| {
                let q = pose.transform(&Point3::new(
                    p.xyz[0] as f64,
                    p.xyz[1] as f64,
                    p.xyz[2] as f64,
                ));
                q.z > 0.0
                    && cam
                        .project_visible(&q.coords)
                        .is_ok_and(|px| cam.is_valid_pixel(&px))
            })
            .count()
    }

    /// What truth.json records of the gantry's sensors.
    fn acquisition(&self, world: &World) -> GantryAcquisition {
        let o = self.rig.lidar_origin;
        let heading = 90.0 - self.rig.view_angle.to_degrees();
        GantryAcquisition {
            perspective_heading_pitch_deg: [heading.rem_euclid(360.0), self.rig.pitch_down_deg],
            lidar_height_above_ground_m: o.z - world.height(o.x, o.y),
            lidar_rings_columns: [gantry::RINGS, gantry::COLUMNS],
            lidar_ring_elevations_deg: [gantry::RING_TOP_DEG, gantry::RING_BOTTOM_DEG],
            sweep_points: self.sweeps.iter().map(Vec::len).collect(),
            sweep_points_in_view: self.sweeps.first().map_or(0, |s| self.in_view(s)),
        }
    }
}

/// The true pose in the world's local frame and in the map frame, and the camera's height above
/// the ground: a centre within 10 m of the intersection's centre (cleared of solids 4 m around),
/// 4–12 m up (a gantry: 6–9 m), any yaw, and a tilt of up to 3° (hard) or 0.2°.
fn true_pose(
    rng: &mut ChaCha8Rng,
    world: &mut World,
    hard: bool,
    origin: [f64; 2],
    gantry: bool,
) -> (CamFromMap, CamFromMap, f64) {
    let r = 10.0 * rng.random::<f64>().sqrt();
    let phi = rng.random_range(0.0..TAU);
    let (cx, cy) = (r * phi.cos(), r * phi.sin());
    world.clear_around(cx, cy, 4.0);
    let above = rng.random_range(4.0..12.0);
    // The same draw, mapped onto the gantry's range, keeps every later draw in step.
    let above = if gantry {
        6.0 + (above - 4.0) * 3.0 / 8.0
    } else {
        above
    };
    let cz = world.height(cx, cy) + above;
    let tilt = if hard {
        3f64.to_radians()
    } else {
        0.2f64.to_radians()
    };
    let yaw = rng.random_range(-PI..PI);
    let pitch = rng.random_range(-tilt..tilt);
    let roll = rng.random_range(-tilt..tilt);
    let pose_local = CamFromMap::from_center_ypr(&Point3::new(cx, cy, cz), yaw, pitch, roll);
    let pose = CamFromMap::from_center_ypr(
        &Point3::new(cx + origin[0], cy + origin[1], cz),
        yaw,
        pitch,
        roll,
    );
    (pose_local, pose, above)
}

/// The satellite layer and how it was taken.
struct SatelliteLayer {
    /// The image.
    image: Raster<[u8; 3]>,
    /// The shot: light, view, shift, blur and JPEG quality.
    shot: layers::SatelliteShot,
    /// The sun's azimuth and elevation, degrees.
    sun_az_el: (f64, f64),
    /// The view's angle off nadir, degrees.
    off_nadir_deg: f64,
}

/// The satellite layer, its grid jitter, shift, sun, off-nadir view and JPEG quality drawn from
/// `rng`.
fn satellite_layer(
    rng: &mut ChaCha8Rng,
    world: &World,
    look: &Appearance,
    origin: [f64; 2],
    crs: Crs,
) -> Result<SatelliteLayer> {
    let half = TILE_SIZE_M / 2.0;
    let sat_n = ((TILE_SIZE_M + 2.0 * SAT_MARGIN_M) / MAP_RES).round() as usize;
    let sat_grid = GeoGrid {
        crs,
        x0: origin[0] - half - SAT_MARGIN_M + rng.random_range(0.0..MAP_RES),
        y0: origin[1] + half + SAT_MARGIN_M - rng.random_range(0.0..MAP_RES),
        res: MAP_RES,
        width: sat_n,
        height: sat_n,
    };
    let shift_mag = rng.random_range(0.1..0.3);
    let shift_dir = rng.random_range(0.0..TAU);
    let sat_sun = (rng.random_range(130.0..230.0), rng.random_range(38.0..65.0));
    let off_nadir: f64 = rng.random_range(2.0..12.0);
    let off_az = rng.random_range(0.0..TAU);
    let on = off_nadir.to_radians();
    let shot = layers::SatelliteShot {
        light: Light::from_az_el(sat_sun.0, sat_sun.1, 0.85, 0.3),
        view: Vector3::new(on.sin() * off_az.sin(), on.sin() * off_az.cos(), -on.cos()),
        shift: [shift_mag * shift_dir.cos(), shift_mag * shift_dir.sin()],
        blur_px: 1.5,
        jpeg_quality: rng.random_range(55..80),
    };
    let satellite = layers::satellite(
        world,
        look,
        &sat_grid,
        origin,
        &shot,
        &world.satellite_parked,
    )?;
    Ok(SatelliteLayer {
        image: satellite,
        shot,
        sun_az_el: sat_sun,
        off_nadir_deg: off_nadir,
    })
}

/// The camera's sensor: noisier, blurrier and more vignetted in a hard scene.
fn sensor(hard: bool) -> Sensor {
    if hard {
        Sensor {
            blur_px: 0.7,
            vignetting: 0.45,
            full_well: 900.0,
            read_noise: 0.006,
            gamma: 2.2,
        }
    } else {
        Sensor {
            blur_px: 0.6,
            vignetting: 0.3,
            full_well: 3000.0,
            read_noise: 0.003,
            gamma: 2.2,
        }
    }
}

/// The receiver's log of a scene and what it was drawn from.
struct GpsLog {
    /// The NMEA 0183 log.
    nmea: String,
    /// The log's first UTC time.
    start: gps::UtcStart,
    /// The receiver's true position, [lat, lon].
    truth_wgs84: [f64; 2],
    /// The bias and noise σ of the fixes, metres.
    sigma_bias_noise_m: [f64; 2],
}

/// The receiver's log at the camera of `pose`, drawn from `rng`.
fn gps_log(
    rng: &mut ChaCha8Rng,
    hard: bool,
    pose: &CamFromMap,
    crs: Crs,
    at: Option<gps::UtcStart>,
) -> Result<GpsLog> {
    let (bias_s, noise_s) = if hard { (4.0, 3.0) } else { (1.5, 1.3) };
    let gm = gps::GpsModel {
        bias_sigma: bias_s,
        noise_sigma: noise_s,
        tau_s: 10.0,
        duration_s: rng.random_range(30..=60),
        quality: if hard { 1 } else { 2 },
        hdop: if hard { (1.1, 2.4) } else { (0.7, 1.2) },
        sats: if hard { (6, 10) } else { (9, 14) },
    };
    let c_map = pose.center();
    let to_wgs = |x: f64, y: f64| Ok(crate::geo::map_to_wgs84(crs, x, y)?);
    let fixes = gps::track(rng, [c_map.x, c_map.y, c_map.z], &gm, to_wgs)?;
    let start = gps::UtcStart {
        year: 2026,
        month: rng.random_range(4..=10),
        day: rng.random_range(1..=28),
        sec_of_day: rng.random_range(13 * 3600..21 * 3600),
    };
    // A day's captures start the log at the first capture (the draws above are made all the
    // same, so the rest of the scene does not depend on it).
    let start = at.unwrap_or(start);
    let nmea = gps::nmea_log(&fixes, &start, GEOID_SEP);
    let (lat, lon) = to_wgs(c_map.x, c_map.y)?;
    Ok(GpsLog {
        nmea,
        start,
        truth_wgs84: [lat, lon],
        sigma_bias_noise_m: [bias_s, noise_s],
    })
}

/// Control points: every marking corner as a tile point, and as truth those the true camera
/// sees unoccluded (within [`CONTROL_MAX_THETA_DEG`] of its axis).
fn control_points(
    world: &World,
    statics: &[Solid],
    origin: [f64; 2],
    pose: &CamFromMap,
    pose_local: &CamFromMap,
    camera_true: &Camera,
) -> (Vec<TruthPoint>, Vec<ControlPoint>) {
    let cands = world.control_candidates();
    let mut control_points = Vec::new();
    let mut tile_points = Vec::new();
    let center_l = pose_local.center().coords;
    for (id, x, y) in cands {
        let z = world.height(x, y);
        let map = [x + origin[0], y + origin[1], z];
        tile_points.push(ControlPoint {
            id: id.clone(),
            xyz: map,
        });
        let pc = pose.transform(&Point3::new(map[0], map[1], map[2]));
        let Ok(px) = camera_true.project_visible(&pc.coords) else {
            continue;
        };
        if !camera_true.is_valid_pixel(&px)
            || pc.z / pc.coords.norm() < CONTROL_MAX_THETA_DEG.to_radians().cos()
        {
            continue;
        }
        let to = Vector3::new(x, y, z) - center_l;
        let dist = to.norm();
        let d = to / dist;
        let blocked = solids::nearest(statics, &center_l, &d, dist - 0.05).is_some();
        let first =
            render::intersect_ground(world, &center_l, &d).is_some_and(|t| (t - dist).abs() < 0.02);
        if !blocked && first {
            control_points.push(TruthPoint {
                id,
                map,
                pixel: [px.x, px.y],
            });
        }
    }
    (control_points, tile_points)
}

/// A UTC time as pose files write it.
fn utc_string(s: &gps::UtcStart) -> String {
    format!(
        "{:04}-{:02}-{:02}T{:02}:{:02}:{:02}Z",
        s.year,
        s.month,
        s.day,
        s.sec_of_day / 3600,
        (s.sec_of_day / 60) % 60,
        s.sec_of_day % 60
    )
}

impl Scene {
    /// truth.json content (docs/interfaces.md, "Scene directory"): a full `infraloc.pose.v1` document of the true pose
    /// (so every pose reader accepts it) plus control points, GPS truth, seed and settings.
    pub fn truth_json(&self) -> serde_json::Value {
        let stamp = self.capture_time();
        let mut pf = crate::posefile::PoseFile::new(&self.pose, self.crs, &self.tile.id, stamp);
        pf.intrinsics = serde_json::to_value(&self.camera_true).unwrap_or_default();
        pf.stages = vec![serde_json::json!({ "name": "truth" })];
        let extra = [
            ("intrinsics_given", serde_json::to_value(&self.camera_given)),
            ("control_points", serde_json::to_value(&self.control_points)),
            (
                "gps_truth_wgs84",
                serde_json::to_value(self.gps_truth_wgs84),
            ),
            ("seed", serde_json::to_value(self.settings.seed)),
            ("settings", serde_json::to_value(self.settings)),
            ("acquisition", serde_json::to_value(&self.acquisition)),
        ];
        for (k, v) in extra {
            pf.extra.insert(k.into(), v.unwrap_or_default());
        }
        serde_json::to_value(&pf).unwrap_or_default()
    }

    /// The capture's UTC time, as pose files write it.
    pub fn capture_time(&self) -> String {
        utc_string(&self.start)
    }

    /// Width and height of the frames.
    pub fn frame_size(&self) -> (u32, u32) {
        (self.camera_true.width(), self.camera_true.height())
    }

    /// The frames as images (the measuring examples feed them to the temporal median as
    /// `localize` does after reading the PNGs, which are lossless).
    pub fn frame_images(&self) -> Vec<image::GrayImage> {
        let (w, h) = self.frame_size();
        self.frames
            .iter()
            .filter_map(|f| image::GrayImage::from_raw(w, h, f.clone()))
            .collect()
    }

    /// A side-by-side picture: satellite | reflectivity | height | fisheye frame 0, each panel
    /// `panel` pixels high. The three map panels show the same central square of the tile.
    pub(crate) fn montage(&self, panel: u32) -> image::RgbImage {
        use image::imageops::{resize, FilterType};
        let sat = self
            .tile
            .satellite
            .as_ref()
            .expect("a simulated tile has a satellite layer");
        let satimg =
            image::RgbImage::from_fn(sat.grid.width as u32, sat.grid.height as u32, |x, y| {
                image::Rgb(sat.data[y as usize * sat.grid.width + x as usize])
            });
        let refl = &self.tile.reflectivity;
        let g = refl.grid;
        let reflimg = image::RgbImage::from_fn(g.width as u32, g.height as u32, |x, y| {
            let v = refl.data[y as usize * g.width + x as usize];
            if v == layers::REFLECTIVITY_NODATA {
                image::Rgb([90, 0, 0])
            } else {
                let s = ((v as f64 / 160.0).min(1.0).sqrt() * 255.0) as u8;
                image::Rgb([s, s, s])
            }
        });
        // Height: detrended (minus the base slope) to show crown, curbs and lawns.
        let hr = &self.tile.height;
        let det: Vec<f64> = (0..g.len())
            .map(|i| {
                let (mx, my) = g.pixel_center(i % g.width, i / g.width);
                hr.data[i] as f64 - self.world.base(mx - self.origin[0], my - self.origin[1])
            })
            .collect();
        let himg = image::RgbImage::from_fn(g.width as u32, g.height as u32, |x, y| {
            let d = det[y as usize * g.width + x as usize];
            if d.is_nan() {
                image::Rgb([90, 0, 0])
            } else {
                let t = ((d + 0.05) / 0.45).clamp(0.0, 1.0);
                image::Rgb([
                    (255.0 * t) as u8,
                    (255.0 * (1.0 - (2.0 * t - 1.0).abs())) as u8,
                    (255.0 * (1.0 - t)) as u8,
                ])
            }
        });
        let (fw, fh) = self.frame_size();
        let fimg = image::RgbImage::from_fn(fw, fh, |x, y| {
            let v = self.frames[0][(y * fw + x) as usize];
            image::Rgb([v, v, v])
        });
        let fish_w = (panel as f64 * fw as f64 / fh as f64).round() as u32;
        let panels = [
            resize(&satimg, panel, panel, FilterType::Triangle),
            resize(&reflimg, panel, panel, FilterType::Triangle),
            resize(&himg, panel, panel, FilterType::Triangle),
            resize(&fimg, fish_w, panel, FilterType::Triangle),
        ];
        let total: u32 = panels.iter().map(|p| p.width()).sum::<u32>() + 3 * 4;
        let mut out = image::RgbImage::from_pixel(total, panel, image::Rgb([255, 255, 255]));
        let mut x0 = 0;
        for p in &panels {
            image::imageops::replace(&mut out, p, x0 as i64, 0);
            x0 += p.width() + 4;
        }
        out
    }

    /// The reflectivity raster (convenience for callers that need only it).
    pub fn reflectivity(&self) -> &Raster<u8> {
        &self.tile.reflectivity
    }
}

#[cfg(test)]
mod tests;
