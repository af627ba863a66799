//! Diagnostic: every sweep candidate of the initializer on a simulated seed, with its fine-stage
//! PnP result and its errors against truth.
//! `cargo run --release --example diag_candidates -- SEED [small|5mp]`
use infraloc::camera::CameraModel;
use infraloc::config::{Config, GpsSourceKind};
use infraloc::localize::frame::{Frame, MapLayers};
use infraloc::localize::init::coarse::*;
use infraloc::localize::init::ground::*;
use infraloc::localize::init::*;
use infraloc::localize::pipeline::Params;
use infraloc::sim::{self, Difficulty, Lens, Preset, Settings};
use rand::SeedableRng;

fn main() {
    let (scene, (lat, lon, sigma)) = scene_and_prior();
    let tile = &scene.tile;
    let satellite = tile
        .satellite
        .as_ref()
        .expect("the tile has a satellite layer");
    let prior = infraloc::geo::wgs84_to_map(tile.reflectivity.grid.crs, lat, lon).unwrap();
    let cam = &scene.camera_given;
    let (w, h) = scene.frame_size();
    let frames: Vec<image::GrayImage> = scene
        .frames
        .iter()
        .map(|f| image::GrayImage::from_raw(w, h, f.clone()).unwrap())
        .collect();
    let img = infraloc::capture::temporal_median(&frames).unwrap();
    let frame = Frame::new(cam, img.as_raw()).unwrap();
    let mut p = Params::default();
    // DIAG_TOPK=N: a longer sweep list; DIAG_FINE=N: fine stage only for the first N.
    if let Some(k) = std::env::var("DIAG_TOPK").ok().and_then(|s| s.parse().ok()) {
        p.coarse.top_k = k;
    }
    let n_fine = env_count("DIAG_FINE", usize::MAX);
    // DIAG_CLIMB=N: the verifier's MI climb from the first N candidates' sweep poses.
    let n_climb = env_count("DIAG_CLIMB", 0);
    let radius =
        (p.prior_sigmas * sigma).clamp(p.search_radius_range_m.0, p.search_radius_range_m.1);
    let truth = scene.pose;
    let c = truth.center();
    let (ty, tp, tr) = truth.yaw_pitch_roll();
    println!(
        "truth yaw {:.1} pitch {:.2} roll {:.2} h {:.2}; prior err ({:.2},{:.2}) radius {:.1}",
        ty.to_degrees(),
        tp.to_degrees(),
        tr.to_degrees(),
        scene.acquisition.camera_height_above_ground_m,
        prior.0 - c.x,
        prior.1 - c.y,
        radius
    );
    let t = std::time::Instant::now();
    let cands = coarse_candidates(cam, img.as_raw(), satellite, prior, radius, &p.coarse);
    println!(
        "sweep {:.1} s, {} candidates",
        t.elapsed().as_secs_f64(),
        cands.len()
    );
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(p.seed);
    // MI against the LiDAR map (the initializer's independent verifier), at the truth first.
    let ver =
        infraloc::localize::init::verify::MiVerifier::new(cam, img.as_raw(), tile, verify_params());
    let vs = |pose: &infraloc::pose::CamFromMap| {
        ver.verify(pose).map_or("mi –".to_string(), |v| {
            format!("mi {:.4} (n {})", v.mi, v.n)
        })
    };
    let flip = |pose: &infraloc::pose::CamFromMap| {
        pose.perturbed(&nalgebra::Vector3::zeros(), std::f64::consts::PI)
    };
    println!(
        "truth: {}  truth half-turned: {}",
        vs(&truth),
        vs(&flip(&truth))
    );
    let wrap = |a: f64| {
        (a + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI
    };
    // DIAG_ORDER=mi: candidates in decreasing screening MI, as the verified initializer tries them.
    let cands = if std::env::var("DIAG_ORDER").is_ok_and(|s| s == "mi") {
        mi_order(cands, &ver, tile, prior)
    } else {
        cands
    };
    for (i, k) in cands.iter().enumerate() {
        let (ex, ey) = (prior.0 + k.offset[0] - c.x, prior.1 + k.offset[1] - c.y);
        print!(
            "#{i} yaw {:7.1} (err {:6.1}) h {:5.2} pos err {:5.2} score {:.4} | ",
            k.yaw.to_degrees(),
            wrap(k.yaw - ty).to_degrees(),
            k.height,
            ex.hypot(ey),
            k.score
        );
        let zg =
            height_at(&tile.height, prior.0 + k.offset[0], prior.1 + k.offset[1]).unwrap_or(0.0);
        let coarse_pose = infraloc::pose::CamFromMap::from_center_ypr(
            &nalgebra::Point3::new(prior.0 + k.offset[0], prior.1 + k.offset[1], zg + k.height),
            k.yaw,
            0.0,
            0.0,
        );
        print!(
            "sweep {} | ",
            ver.screen(&coarse_pose)
                .map_or("mi –".to_string(), |v| format!(
                    "mi {:.4} (n {})",
                    v.mi, v.n
                ))
        );
        if i < n_climb {
            if let Some(up) = ver.climb(&coarse_pose) {
                let uc = up.pose.center();
                print!(
                    "climb: mi {:.4} err {:.2} m z {:.2} yaw {:.1}° | ",
                    up.mi,
                    (uc.x - c.x).hypot(uc.y - c.y),
                    uc.z - c.z,
                    wrap(up.pose.yaw_pitch_roll().0 - ty).to_degrees()
                );
            }
        }
        if i >= n_fine {
            println!();
            continue;
        }
        let t = std::time::Instant::now();
        match fine_stage(
            &frame,
            MapLayers {
                satellite,
                heights: &tile.height,
            },
            prior,
            k,
            &p.fine,
            &mut rng,
        ) {
            Ok(f) => {
                let pc = f.pose.center();
                let (_, pp, pr) = f.pose.yaw_pitch_roll();
                println!(
                    "pnp {}/{} rms {:.2} px: err {:.3} m z {:.3} yaw {:.2}° tilt {:.1}/{:.1} ({:.1} s) {} flip {}",
                    f.inliers,
                    f.matches,
                    f.rms_px,
                    (pc.x - c.x).hypot(pc.y - c.y),
                    pc.z - c.z,
                    wrap(f.pose.yaw_pitch_roll().0 - ty).to_degrees(),
                    pp.to_degrees(),
                    pr.to_degrees(),
                    t.elapsed().as_secs_f64(),
                    vs(&f.pose),
                    vs(&flip(&f.pose)),
                );
            }
            Err(e) => println!("pnp failed: {e}"),
        }
    }
    let _ = cam.width();
}

/// The hard scene of the command line's seed and preset, and the prior from its NMEA log.
fn scene_and_prior() -> (sim::Scene, (f64, f64, f64)) {
    let seed: u64 = std::env::args()
        .nth(1)
        .expect("seed")
        .parse()
        .expect("seed");
    let preset = match std::env::args().nth(2).as_deref() {
        Some("5mp") => Preset::FiveMp,
        _ => Preset::Small,
    };
    let scene = sim::generate(&Settings {
        seed,
        preset,
        difficulty: Difficulty::Hard,
        lens: Lens::Mei,
        frames: 5,
        intrinsics: Default::default(),
        times: 1,
        low_sun: false,
    })
    .unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let nmea = tmp.path().join("gps.nmea");
    std::fs::write(&nmea, &scene.nmea).unwrap();
    let mut g = Config::default().gps;
    g.source = GpsSourceKind::NmeaFile;
    g.path = Some(nmea);
    let prior = infraloc::gps_serial::acquire_prior(&g)
        .unwrap()
        .position()
        .unwrap();
    (scene, prior)
}

/// The verifier's settings, with DIAG_VERIFY="off_nadir_deg,max_radius_m,blur_m,bins,points"
/// overriding them for experiments.
fn verify_params() -> infraloc::localize::init::verify::VerifyParams {
    let mut v = infraloc::localize::init::verify::VerifyParams::default();
    if let Ok(s) = std::env::var("DIAG_VERIFY") {
        let f: Vec<f64> = s.split(',').filter_map(|t| t.parse().ok()).collect();
        if f.len() == 5 {
            v.max_off_nadir_deg = f[0];
            v.max_radius_m = f[1];
            v.blur_m = f[2];
            v.bins = f[3] as usize;
            v.points = f[4] as usize;
        }
    }
    v
}

/// The candidates in decreasing screening MI, as the verified initializer tries them.
fn mi_order(
    cands: Vec<infraloc::localize::init::sweep::Candidate>,
    ver: &infraloc::localize::init::verify::MiVerifier,
    tile: &infraloc::map::Tile,
    prior: (f64, f64),
) -> Vec<infraloc::localize::init::sweep::Candidate> {
    let key = |k: &infraloc::localize::init::sweep::Candidate| {
        ver.screen(&candidate_pose(&tile.height, prior, k))
            .map_or(f64::NEG_INFINITY, |v| v.mi)
    };
    let mut keyed: Vec<(f64, infraloc::localize::init::sweep::Candidate)> =
        cands.iter().map(|k| (key(k), *k)).collect();
    keyed.sort_by(|a, b| b.0.total_cmp(&a.0));
    keyed.into_iter().map(|(_, k)| k).collect()
}

/// The count in environment variable `name`, or `default`.
fn env_count(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}
