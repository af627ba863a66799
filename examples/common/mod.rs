//! Helpers shared by the measuring examples (`drift_cost`, `scaling`, `drift_verdicts`,
//! `diag_s11`, `diag_ground`, `pipeline_accuracy`, `frames_pooling`; `benches/refine.rs` uses the camera).
//! Included with `#[path]`, so each user compiles only what it calls.
#![allow(dead_code, unreachable_pub)]

use infraloc::camera::{Camera, Mei};

/// Process CPU time (user + system, all threads), seconds.
pub fn cpu_s() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; the clock id is a constant the kernel knows.
    unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) };
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

/// The `5mp` preset's given intrinsics (scene seed 2), scaled to `width`×`height`: focal
/// lengths and the centre's column with the width, the centre's row with the height.
pub fn preset_camera(width: u32, height: u32) -> Camera {
    let s = width as f64 / 2448.0;
    Camera::Mei(Mei {
        width,
        height,
        fx: 1199.27 * s,
        fy: 1198.64 * s,
        cx: 1225.22 * s,
        cy: 1026.07 * height as f64 / 2048.0,
        skew: 0.0,
        xi: 1.2,
        k1: -0.2673,
        k2: 0.0929,
        p1: -1.7e-4,
        p2: -3.1e-5,
        fov_deg: Some(185.0),
    })
}

/// A preset by its name on the command line (`small`, `5mp`: the names `infraloc simulate` and
/// the scene files use).
pub fn parse_preset(name: &str) -> Option<infraloc::sim::Preset> {
    serde_json::from_value(serde_json::Value::String(name.to_owned())).ok()
}

/// The settings of `infraloc simulate --difficulty hard` (Mei lens, five frames) for `seed`.
pub fn hard_settings(
    seed: u64,
    preset: infraloc::sim::Preset,
    intrinsics: infraloc::sim::GivenIntrinsics,
) -> infraloc::sim::Settings {
    infraloc::sim::Settings {
        seed,
        preset,
        difficulty: infraloc::sim::Difficulty::Hard,
        lens: infraloc::sim::Lens::Mei,
        frames: 5,
        intrinsics,
        times: 1,
        low_sun: false,
    }
}

/// What `infraloc localize` reads from a simulated scene's directory, made from the scene in
/// memory: the camera through its YAML, the temporal median of the frames, the tile through the
/// GeoTIFF cache (in `dir`), and the prior from the NMEA log with the default `[gps]` settings.
pub struct SceneInputs {
    /// The camera handed to the localizer (the given intrinsics, or the true ones).
    pub camera: Camera,
    /// Temporal median of the frames.
    pub image: image::GrayImage,
    /// The tile as read back from the cache.
    pub tile: infraloc::map::Tile,
    /// The prior's map position.
    pub prior_xy: (f64, f64),
    /// The prior's σ, metres.
    pub prior_sigma_m: f64,
    /// The temporary directory holding the tile cache and the NMEA log.
    pub dir: tempfile::TempDir,
}

/// [`SceneInputs`] of `scene`; `true_intrinsics` hands over the scene's true camera instead of
/// the given one.
pub fn scene_inputs(
    scene: &infraloc::sim::Scene,
    true_intrinsics: bool,
) -> infraloc::Result<SceneInputs> {
    use infraloc::config::{Config, GpsSourceKind};
    let dir = tempfile::tempdir().map_err(|e| infraloc::Error::io(std::env::temp_dir(), e))?;
    let tiles = dir.path().join("tiles");
    infraloc::map::cache::write_tile(&tiles, &scene.tile)?;
    let nmea = dir.path().join("gps.nmea");
    std::fs::write(&nmea, &scene.nmea).map_err(|e| infraloc::Error::io(&nmea, e))?;
    let camera = infraloc::camera::import::parse_camera(
        &infraloc::camera::import::to_opencv_yaml(if true_intrinsics {
            &scene.camera_true
        } else {
            &scene.camera_given
        }),
        &dir.path().join("camera.yaml"),
    )?;
    let image = infraloc::capture::temporal_median(&scene.frame_images())?;
    let cfg = Config::default();
    let mut g = cfg.gps.clone();
    g.source = GpsSourceKind::NmeaFile;
    g.path = Some(nmea);
    let prior = infraloc::gps_serial::acquire_prior(&g)?;
    let (lat, lon, prior_sigma_m) = prior.position().ok_or_else(|| {
        infraloc::Error::stage(
            infraloc::stage::StageName::Prior,
            "no position from the NMEA log",
        )
    })?;
    let tref = infraloc::map::cache::find_tile(&tiles, lat, lon, cfg.map.search_margin_m)?;
    let tile = infraloc::map::cache::load_tile(&tref.dir)?;
    let prior_xy = infraloc::geo::wgs84_to_map(tile.reflectivity.grid.crs, lat, lon)?;
    Ok(SceneInputs {
        camera,
        image,
        tile,
        prior_xy,
        prior_sigma_m,
        dir,
    })
}

/// A pose from `pipeline_accuracy`'s per-seed `poses` record: `[x, y, z, yaw, pitch, roll]`
/// (map metres, degrees); `None` when it is not six numbers.
pub fn pose_of(v: &serde_json::Value) -> Option<infraloc::pose::CamFromMap> {
    let a: Vec<f64> = v
        .as_array()?
        .iter()
        .map(|x| x.as_f64())
        .collect::<Option<_>>()?;
    (a.len() == 6).then(|| {
        infraloc::pose::CamFromMap::from_center_ypr(
            &nalgebra::Point3::new(a[0], a[1], a[2]),
            a[3].to_radians(),
            a[4].to_radians(),
            a[5].to_radians(),
        )
    })
}

/// Depth of the ground below `pose`'s camera centre in `tile` (at least 1 m): the pivot the
/// pipeline's polish tilts about.
pub fn tilt_pivot(tile: &infraloc::map::Tile, pose: &infraloc::pose::CamFromMap) -> Option<f64> {
    let c = pose.center();
    infraloc::localize::init::ground::height_at(&tile.height, c.x, c.y).map(|g| (c.z - g).max(1.0))
}

/// The search box of the pipeline's polish (`pp.bound` on each axis, pitch and roll free) about
/// `pivot`, with `search`'s other settings: the fixed point set the polish scores on.
pub fn polish_box(
    pp: &infraloc::localize::refine::polish::PolishParams,
    search: &infraloc::localize::mi::space::SearchConfig,
    pivot: Option<f64>,
) -> infraloc::localize::mi::space::SearchConfig {
    use infraloc::localize::mi::space::{AxisRange, SearchConfig, SearchSpec};
    let ax = |half: f64| AxisRange {
        half,
        step: half / 2.0,
    };
    SearchConfig {
        spec: SearchSpec {
            x: ax(pp.bound[0]),
            y: ax(pp.bound[1]),
            z: ax(pp.bound[2]),
            yaw: ax(pp.bound[3]),
            pitch: Some(ax(pp.bound[4])),
            roll: Some(ax(pp.bound[5])),
            tilt_pivot_m: pivot,
        },
        ..*search
    }
}

/// The scene's truth as `localize --truth` reads it: its `truth.json` written and parsed back.
pub fn scene_truth(scene: &infraloc::sim::Scene) -> infraloc::Result<infraloc::eval::truth::Truth> {
    let text = serde_json::to_string(&scene.truth_json())
        .map_err(|e| infraloc::Error::Invalid(format!("truth.json: {e}")))?;
    infraloc::eval::truth::parse_truth(&text, std::path::Path::new("truth.json"))
}

/// The gap-free image of `tile` seen by `camera` at `pose`: each pixel the reflectivity
/// (bilinear over valid cells) where its ray meets the raw height layer; 0 elsewhere. Image and
/// LiDAR raster agree exactly at `pose`: the simulator's modality gap is gone (docs/accuracy.md,
/// "Where the ground error comes from").
pub fn gap_free_image(
    camera: &infraloc::camera::Camera,
    tile: &infraloc::map::Tile,
    pose: &infraloc::pose::CamFromMap,
) -> Vec<u8> {
    use infraloc::camera::CameraModel;
    use infraloc::geo::georef::{self, HeightSurface, PoseWithCovariance, Surface};
    let (w, h) = (camera.width() as usize, camera.height() as usize);
    let Some(hs) = HeightSurface::with_smoothing(&tile.height, 0.0) else {
        return vec![0; w * h];
    };
    let pc = PoseWithCovariance {
        pose: *pose,
        covariance: None,
    };
    let params = georef::Params {
        wgs84: false,
        ..georef::Params::default()
    };
    let pixels: Vec<[f64; 2]> = (0..w * h)
        .map(|k| [(k % w) as f64, (k / w) as f64])
        .collect();
    let refl = &tile.reflectivity;
    let g = refl.grid;
    let at = |c: usize, r: usize| -> Option<f64> {
        let v = refl.data[r * g.width + c];
        (refl.nodata != Some(v)).then_some(v as f64)
    };
    georef::georef_batch(camera, &pc, &Surface::Heights(hs), g.crs, &pixels, &params)
        .iter()
        .map(|m| {
            if m.status != georef::Status::Ok {
                return 0;
            }
            let (fc, fr) = g.to_pixel(m.enh[0], m.enh[1]);
            let (c0, r0) = (fc.floor(), fr.floor());
            if c0 < 0.0 || r0 < 0.0 || c0 + 1.0 >= g.width as f64 || r0 + 1.0 >= g.height as f64 {
                return 0;
            }
            let (u, v) = (fc - c0, fr - r0);
            let (c0, r0) = (c0 as usize, r0 as usize);
            match (
                at(c0, r0),
                at(c0 + 1, r0),
                at(c0, r0 + 1),
                at(c0 + 1, r0 + 1),
            ) {
                (Some(a), Some(b), Some(c), Some(d)) => {
                    let x = a * (1.0 - u) * (1.0 - v)
                        + b * u * (1.0 - v)
                        + c * (1.0 - u) * v
                        + d * u * v;
                    x.round().clamp(1.0, 255.0) as u8
                }
                _ => 0,
            }
        })
        .collect()
}

/// Real image/point-set pairs for the estimator probes (`pv_probe`, `pv_region`): each pair's
/// gray image (row-major, the camera's size) and its points, read from the `[IMAGE, POINTS]`
/// path pairs.
pub struct RealPairs {
    /// Gray images.
    pub grays: Vec<Vec<u8>>,
    /// Point sets.
    pub sets: Vec<Vec<infraloc::map::GroundPoint>>,
    /// The camera's valid mask.
    pub mask: Vec<u8>,
}

impl RealPairs {
    /// Read the pairs for `cam`.
    pub fn read(
        cam: &Camera,
        pairs: &[(std::path::PathBuf, std::path::PathBuf)],
    ) -> Result<Self, Box<dyn std::error::Error>> {
        use infraloc::camera::CameraModel;
        let (mut grays, mut sets) = (Vec::new(), Vec::new());
        for (img, pts) in pairs {
            grays.push(image::open(img)?.to_luma8().into_raw());
            sets.push(infraloc::points_io::read_points(pts)?);
        }
        Ok(RealPairs {
            grays,
            sets,
            mask: cam.valid_mask(),
        })
    }

    /// The pairs as the estimator's views.
    pub fn views(&self) -> Vec<infraloc::localize::mi::objective::View<'_>> {
        self.grays
            .iter()
            .zip(&self.sets)
            .map(|(g, p)| infraloc::localize::mi::objective::View {
                gray: g,
                mask: &self.mask,
                points: p,
            })
            .collect()
    }
}

/// A pose argument of the estimator probes: `POSE.json` or `POSE.json@DX,DY,DZ,DYAW`, the pose
/// file's pose moved by offsets (m, m, m, deg) as `refine`'s report gives them.
pub fn pose_arg(arg: &str) -> Result<infraloc::pose::CamFromMap, Box<dyn std::error::Error>> {
    let (file, moved) = arg.split_once('@').unwrap_or((arg, ""));
    let pose = infraloc::posefile::read_pose(std::path::Path::new(file))?.pose;
    if moved.is_empty() {
        return Ok(pose);
    }
    let o: Vec<f64> = moved.split(',').map(str::parse).collect::<Result<_, _>>()?;
    if o.len() != 4 {
        return Err(format!("{arg}: POSE@DX,DY,DZ,DYAW takes four offsets").into());
    }
    Ok(infraloc::localize::mi::space::pose_at(
        &pose,
        &[o[0], o[1], o[2], o[3], 0.0, 0.0],
    ))
}
