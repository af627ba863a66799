//! `infraloc simulate`: generate a scene in memory ([`crate::sim`]) and write the scene directory
//! of docs/interfaces.md, "Scene directory".

use crate::camera::{Camera, CameraModel};
use crate::config::{Config, GpsSourceKind};
use crate::error::{Error, Result};
use crate::map::cache::{write_tile_with, Provenance};
use crate::map::Crs;
use crate::pose::CamFromMap;
use crate::posefile::PoseFile;
use crate::sim::error::SimError;
use crate::sim::{self, Difficulty, GantryScene, GivenIntrinsics, Lens, Preset, Scene, Settings};
use nalgebra::Vector3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::fs;
use std::path::{Path, PathBuf};

/// Image preset.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum PresetArg {
    /// 1024×1024, fast (tests).
    Small,
    /// 2448×2048 Sony IMX264 with a 185° lens.
    #[value(name = "5mp")]
    FiveMp,
    /// `small`'s fisheye on a 6–9 m gantry, with a perspective camera, a 64-ring LiDAR sweep
    /// and a low sun (docs/simulator.md, "Gantry preset").
    Gantry,
}

/// Difficulty.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum DifficultyArg {
    /// Level camera, good GPS, exact intrinsics, light traffic.
    Easy,
    /// Tilted camera, 5 m GPS, calibrated (not exact) intrinsics, dense traffic.
    Hard,
}

/// Lens model.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum LensArg {
    /// Mei / OpenCV omnidir.
    Mei,
    /// Equidistant / OpenCV fisheye.
    Equidistant,
}

/// How `hard`'s given intrinsics are made.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum IntrinsicsArg {
    /// `infraloc calibrate`'s own result on rendered checkerboard views of the true camera.
    Calibrated,
    /// The true ones with a drawn focal and principal-point offset.
    Offset,
}

/// Arguments of `simulate`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Output directory (created; existing files in it are overwritten).
    #[arg(long)]
    pub out: PathBuf,
    /// Seed: the same seed and settings give byte-identical output.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Image preset.
    #[arg(long, value_enum, default_value = "small")]
    pub preset: PresetArg,
    /// Difficulty.
    #[arg(long, value_enum, default_value = "hard")]
    pub difficulty: DifficultyArg,
    /// Lens model of the simulated camera.
    #[arg(long, value_enum, default_value = "mei")]
    pub lens: LensArg,
    /// Number of fisheye frames (of each time, with --times).
    #[arg(long, default_value_t = 5)]
    pub frames: u32,
    /// Capture the scene at K times of one day (1..=24), each a burst of --frames under that
    /// time's sun, with its own shadows, traffic and sensor noise; pose, map tile and LiDAR stay
    /// the same. Writes times/NN/ (the bursts), times/NN.png (their temporal medians) and each
    /// time's UTC and sun in truth.json; frames/ is the first time's burst (docs/simulator.md,
    /// "Times of day").
    #[arg(long, value_name = "K", default_value_t = 1)]
    pub times: u32,
    /// Keep the sun 8–25° up at every time (a day near the winter solstice): long shadows all
    /// day. The gantry preset's times always have a low sun.
    #[arg(long)]
    pub low_sun: bool,
    /// How a `hard` scene's camera.yaml is made (`easy` gets the true intrinsics): the product's
    /// calibrator run on 16 rendered checkerboard views of the true camera, which leaves the
    /// error a real install has, or a drawn offset from the true ones (docs/simulator.md).
    #[arg(long, value_enum, default_value = "calibrated")]
    pub given_intrinsics: IntrinsicsArg,
    /// Also write a side-by-side PNG (satellite | reflectivity | height | fisheye) here.
    #[arg(long)]
    pub montage: Option<PathBuf>,
    /// Also write the tile's LiDAR as a LAZ point cloud (intensity, RGB, class 2 ground) for
    /// `tile build`.
    #[arg(long, value_name = "FILE")]
    pub lidar_laz: Option<PathBuf>,
    /// Checkerboard views instead of a scene.
    #[command(flatten)]
    pub board: BoardArgs,
}

/// `simulate --checkerboard N` and its options.
#[derive(Debug, Default, clap::Args)]
pub struct BoardArgs {
    /// Instead of a scene, render N fisheye views of a checkerboard (docs/calibrate.md,
    /// "Simulated boards"): OUT/NNN.png, the true camera.yaml, the true corners.yaml and
    /// checkerboard.json.
    #[arg(long, value_name = "N")]
    pub checkerboard: Option<usize>,
    /// With --checkerboard: inner corners COLSxROWS [default: 9x6].
    #[arg(long, requires = "checkerboard", value_parser = super::calibrate::parse_pattern)]
    pub pattern: Option<(usize, usize)>,
    /// With --checkerboard: side of a square, metres [default: 0.04].
    #[arg(long, requires = "checkerboard")]
    pub square: Option<f64>,
    /// With --checkerboard: the true camera (any intrinsics file --camera reads) [default: the
    /// true camera of the scene this seed, preset and lens would give].
    #[arg(long, requires = "checkerboard")]
    pub camera: Option<PathBuf>,
}

impl Args {
    /// The generator settings these arguments ask for.
    pub(crate) fn settings(&self) -> Settings {
        Settings {
            seed: self.seed,
            preset: match self.preset {
                PresetArg::Small => Preset::Small,
                PresetArg::FiveMp => Preset::FiveMp,
                PresetArg::Gantry => Preset::Gantry,
            },
            difficulty: match self.difficulty {
                DifficultyArg::Easy => Difficulty::Easy,
                DifficultyArg::Hard => Difficulty::Hard,
            },
            lens: match self.lens {
                LensArg::Mei => Lens::Mei,
                LensArg::Equidistant => Lens::Equidistant,
            },
            frames: self.frames,
            intrinsics: match self.given_intrinsics {
                IntrinsicsArg::Offset => GivenIntrinsics::Offset,
                IntrinsicsArg::Calibrated => GivenIntrinsics::Calibrated,
            },
            times: self.times,
            low_sun: self.low_sun,
        }
    }
}

/// Run `simulate`.
pub(super) fn run(a: Args) -> Result<()> {
    if let Some(n) = a.board.checkerboard {
        return checkerboard(&a, n);
    }
    let scene = sim::generate(&a.settings())?;
    write_scene(&scene, &a.out)?;
    if let Some(p) = &a.lidar_laz {
        crate::map::cloud::write_lidar_laz(&scene.tile, p)?;
    }
    if let Some(m) = &a.montage {
        scene
            .montage(512)
            .save(m)
            .map_err(|e| Error::output(m.display().to_string(), e))?;
    }
    let times = match scene.times.len() {
        0 | 1 => String::new(),
        k => format!(" at each of {k} times"),
    };
    println!(
        "simulate: wrote {} ({} frames{times}, {} control points, tile {})",
        a.out.display(),
        scene.frames.len(),
        scene.control_points.len(),
        scene.tile.id
    );
    Ok(())
}

fn write(path: &Path, bytes: impl AsRef<[u8]>) -> Result<()> {
    fs::write(path, bytes).map_err(|e| Error::io(path, e))
}

/// File name of frame `i`.
pub(crate) fn frame_name(i: usize) -> String {
    format!("{i:03}.png")
}

/// Write the scene directory (docs/interfaces.md, "Scene directory") into `dir`.
pub(super) fn write_scene(scene: &Scene, dir: &Path) -> Result<()> {
    let (w, h) = scene.frame_size();
    write_burst(&dir.join("frames"), w, h, &scene.frames)?;
    write_times(scene, dir)?;
    let mut cam_yaml = crate::camera::import::to_opencv_yaml(&scene.camera_given);
    if let Some(s) = &scene.camera_sigma {
        cam_yaml.push_str(&s.yaml_lines());
    }
    write(&dir.join("camera.yaml"), cam_yaml)?;
    write(&dir.join("gps.nmea"), &scene.nmea)?;
    let s = &scene.settings;
    let provenance = Provenance {
        sources: vec![format!(
            "infraloc simulate --seed {} --preset {} --difficulty {} --lens {}",
            s.seed,
            serde_json::to_value(s.preset).ok().and_then(|v| v.as_str().map(String::from)).unwrap_or_default(),
            serde_json::to_value(s.difficulty).ok().and_then(|v| v.as_str().map(String::from)).unwrap_or_default(),
            serde_json::to_value(s.lens).ok().and_then(|v| v.as_str().map(String::from)).unwrap_or_default(),
        )],
        note: Some("simulated scene; heights orthometric (GGA altitude = height, geoid separation -34.5 m)".into()),
        ..Provenance::default()
    };
    write_tile_with(&dir.join("tiles"), &scene.tile, &provenance)?;
    let truth = serde_json::to_string_pretty(&scene.truth_json())
        .map_err(|e| Error::output("truth.json", e))?;
    write(&dir.join("truth.json"), truth + "\n")?;
    if let Some(g) = &scene.gantry {
        write_gantry(scene, g, dir)?;
    }
    let mut cfg = Config::default();
    cfg.camera.intrinsics_file = Some(PathBuf::from("camera.yaml"));
    cfg.camera.frames = Some(PathBuf::from("frames"));
    cfg.camera.frame_count = scene.frames.len() as u32;
    cfg.gps.source = GpsSourceKind::NmeaFile;
    cfg.gps.path = Some(PathBuf::from("gps.nmea"));
    cfg.map.tiles = PathBuf::from("tiles");
    // `infraloc daemon --config DIR/infraloc.toml` runs the service on the scene, socket included.
    cfg.daemon.socket = PathBuf::from("control.sock");
    let text = toml::to_string(&cfg).map_err(|e| Error::output("infraloc.toml", e))?;
    write(
        &dir.join("infraloc.toml"),
        format!(
            "# Written by `infraloc simulate`: localizes this scene with no other flags.\n{text}"
        ),
    )
}

/// Largest offset of the gantry's start.json from the truth: x and y, metres.
const START_XY_M: f64 = 0.4;
/// Largest z offset of start.json, metres.
const START_Z_M: f64 = 0.2;
/// Largest yaw offset of start.json, degrees.
const START_YAW_DEG: f64 = 1.5;

/// One `w`×`h` gray frame as an image.
fn gray(path: &Path, w: u32, h: u32, pixels: &[u8]) -> Result<image::GrayImage> {
    image::GrayImage::from_raw(w, h, pixels.to_vec())
        .ok_or_else(|| Error::output(path.display().to_string(), "frame buffer size"))
}

/// Write one PNG frame of `w`×`h` gray pixels.
fn write_png(path: &Path, w: u32, h: u32, pixels: &[u8]) -> Result<()> {
    gray(path, w, h, pixels)?
        .save(path)
        .map_err(|e| Error::output(path.display().to_string(), e))
}

/// Write a burst as `dir`/000.png, 001.png, … (creating `dir`).
fn write_burst(dir: &Path, w: u32, h: u32, frames: &[Vec<u8>]) -> Result<()> {
    fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    for (i, f) in frames.iter().enumerate() {
        write_png(&dir.join(frame_name(i)), w, h, f)?;
    }
    Ok(())
}

/// A day's captures (docs/simulator.md, "Times of day"): each time's burst in times/NN/ and its
/// temporal median, what a node keeps of a run, in times/NN.png; with a gantry also its
/// perspective frames, its sweeps and perspective/pairs_times.tsv, which pairs each time's first
/// perspective frame with the sweep taken with it.
fn write_times(scene: &Scene, dir: &Path) -> Result<()> {
    let (w, h) = scene.frame_size();
    let mut pairs = Vec::new();
    for (t, c) in scene.times.iter().enumerate() {
        let tdir = dir.join(sim::time_dir(t));
        write_burst(&tdir, w, h, &c.frames)?;
        let burst = c
            .frames
            .iter()
            .map(|f| gray(&tdir, w, h, f))
            .collect::<Result<Vec<_>>>()?;
        let mp = dir.join(sim::time_median(t));
        crate::capture::temporal_median(&burst)
            .map_err(|e| Error::output(mp.display().to_string(), e))?
            .save(&mp)
            .map_err(|e| Error::output(mp.display().to_string(), e))?;
        if let Some(g) = &scene.gantry {
            let cam = &g.rig.camera;
            let pdir = dir.join("perspective").join(sim::time_dir(t));
            write_burst(&pdir, cam.width(), cam.height(), &c.perspective)?;
            let ldir = dir.join("lidar").join(sim::time_dir(t));
            fs::create_dir_all(&ldir).map_err(|e| Error::io(&ldir, e))?;
            for (i, s) in c.sweeps.iter().enumerate() {
                write(&ldir.join(format!("{i:03}.pcd")), sim::gantry::to_pcd(s))?;
            }
            pairs.push((
                PathBuf::from(sim::time_dir(t)).join(frame_name(0)),
                PathBuf::from("../lidar")
                    .join(sim::time_dir(t))
                    .join("000.pcd"),
            ));
        }
    }
    if scene.gantry.is_some() && !pairs.is_empty() {
        fs::create_dir_all(dir.join("perspective")).map_err(|e| Error::io(dir, e))?;
        write(
            &dir.join("perspective").join("pairs_times.tsv"),
            super::pairs::format(&pairs),
        )?;
    }
    Ok(())
}

/// A pose file of the truth (stage `truth`) with the camera's intrinsics.
fn truth_pose(scene: &Scene, pose: &CamFromMap, crs: Crs, tile: &str, cam: &Camera) -> String {
    let mut pf = PoseFile::new(pose, crs, tile, scene.capture_time());
    pf.intrinsics = serde_json::to_value(cam).unwrap_or_default();
    pf.stages = vec![serde_json::json!({ "name": "truth" })];
    pf.to_json()
}

/// The gantry preset's extra files: perspective/ (camera, frames, truths, a start pose, a pairs
/// file) and lidar/ (one sweep per frame and the LiDAR's pose in the map).
fn write_gantry(scene: &Scene, g: &GantryScene, dir: &Path) -> Result<()> {
    let pdir = dir.join("perspective");
    let fdir = pdir.join("frames");
    let ldir = dir.join("lidar");
    for d in [&fdir, &ldir] {
        fs::create_dir_all(d).map_err(|e| Error::io(d, e))?;
    }
    let cam = &g.rig.camera;
    let (w, h) = (cam.width(), cam.height());
    let mut pairs = Vec::new();
    for (i, (f, s)) in g.frames.iter().zip(&g.sweeps).enumerate() {
        write_png(&fdir.join(frame_name(i)), w, h, f)?;
        let pcd = format!("{i:03}.pcd");
        write(&ldir.join(&pcd), sim::gantry::to_pcd(s))?;
        pairs.push((
            PathBuf::from("frames").join(frame_name(i)),
            PathBuf::from("../lidar").join(pcd),
        ));
    }
    write(&pdir.join("pairs.tsv"), super::pairs::format(&pairs))?;
    write(
        &pdir.join("camera.yaml"),
        crate::camera::import::to_opencv_yaml(cam),
    )?;
    write(
        &pdir.join("truth.json"),
        truth_pose(scene, &g.pose, scene.crs, &scene.tile.id, cam),
    )?;
    let in_lidar = g.rig.pose_in_lidar();
    write(
        &pdir.join("truth_lidar.json"),
        truth_pose(scene, &in_lidar, Crs::Local, "", cam),
    )?;
    // A start inside refine's default search box, drawn from the scene's seed.
    let mut rng = ChaCha8Rng::seed_from_u64(scene.settings.seed ^ 0x57A2_7000);
    let mut u = |a: f64| rng.random_range(-a..=a);
    let start = in_lidar.perturbed(
        &Vector3::new(u(START_XY_M), u(START_XY_M), u(START_Z_M)),
        u(START_YAW_DEG).to_radians(),
    );
    let mut pf = PoseFile::new(&start, Crs::Local, "", scene.capture_time());
    pf.stages = vec![
        serde_json::json!({ "name": "start", "note": "the truth_lidar.json pose moved by a seeded offset" }),
    ];
    write(&pdir.join("start.json"), pf.to_json())?;
    let rot = g.rig.lidar_rotation.matrix();
    let o = g.rig.lidar_origin;
    let lidar = serde_json::json!({
        "crs": scene.crs.to_string(),
        "origin_map": [o.x + scene.origin[0], o.y + scene.origin[1], o.z],
        "rotation_map_from_lidar": [
            [rot[(0, 0)], rot[(0, 1)], rot[(0, 2)]],
            [rot[(1, 0)], rot[(1, 1)], rot[(1, 2)]],
            [rot[(2, 0)], rot[(2, 1)], rot[(2, 2)]],
        ],
        "rings": sim::gantry::RINGS,
        "columns": sim::gantry::COLUMNS,
        "ring_elevations_deg": [sim::gantry::RING_TOP_DEG, sim::gantry::RING_BOTTOM_DEG],
        "sweeps": g.sweeps.iter().map(Vec::len).collect::<Vec<_>>(),
    });
    let text = serde_json::to_string_pretty(&lidar).map_err(|e| Error::output("lidar.json", e))?;
    write(&ldir.join("lidar.json"), text + "\n")
}

/// `simulate --checkerboard N`: render the views and write them with their truth.
fn checkerboard(a: &Args, n: usize) -> Result<()> {
    use crate::sim::checkerboard::{render, Board};
    let (cols, rows) = a.board.pattern.unwrap_or((9, 6));
    let square = a.board.square.unwrap_or(0.04);
    if !(square.is_finite() && square > 0.0) || n == 0 {
        return Err(SimError::Checkerboard { views: n, square }.into());
    }
    let cam = match &a.board.camera {
        Some(p) => crate::camera::load_camera(p)?,
        None => sim::scene_true_camera(&a.settings()),
    };
    let board = Board { cols, rows, square };
    let views = render(&cam, &board, n, a.seed);
    fs::create_dir_all(&a.out).map_err(|e| Error::io(&a.out, e))?;
    let (w, h) = (cam.width(), cam.height());
    let object = board.corners();
    let mut full = Vec::new();
    let mut json_views = Vec::new();
    for (i, v) in views.iter().enumerate() {
        let p = a.out.join(frame_name(i));
        image::GrayImage::from_raw(w, h, v.image.clone())
            .ok_or_else(|| Error::output(p.display().to_string(), "image buffer size"))?
            .save(&p)
            .map_err(|e| Error::output(p.display().to_string(), e))?;
        let seen = v.corners.iter().filter(|c| c.is_some()).count();
        if seen == object.len() {
            full.push(crate::calib::View {
                name: frame_name(i),
                object: object.clone(),
                image: v.corners.iter().flatten().copied().collect(),
            });
        }
        let rv = v.pose.r.scaled_axis();
        json_views.push(serde_json::json!({
            "image": frame_name(i),
            "rvec": [rv.x, rv.y, rv.z],
            "tvec": [v.pose.t.x, v.pose.t.y, v.pose.t.z],
            "corners_in_image": seen,
            "corners": v.corners,
        }));
    }
    write(
        &a.out.join("camera.yaml"),
        crate::camera::to_opencv_yaml(&cam),
    )?;
    let obs = crate::calib::Observations {
        width: w,
        height: h,
        views: full,
    };
    write(
        &a.out.join("corners.yaml"),
        crate::calib::corners::to_corners_yaml(&obs),
    )?;
    let truth = serde_json::json!({
        "pattern": [cols, rows],
        "square": square,
        "seed": a.seed,
        "image_size": [w, h],
        "corner_order": "row by row: corner (i, j) at (i*square, j*square, 0) is entry j*cols + i",
        "views": json_views,
    });
    let text =
        serde_json::to_string_pretty(&truth).map_err(|e| Error::output("checkerboard.json", e))?;
    write(&a.out.join("checkerboard.json"), text + "\n")?;
    println!(
        "simulate: wrote {} ({n} views of a {cols}x{rows} board, {} with every corner in the image)",
        a.out.display(),
        obs.views.len()
    );
    Ok(())
}
