//! Diagnostic: every sweep candidate of the initializer on a simulated seed, with its fine-stage
//! PnP result and its errors against truth.
//! `cargo run --release --example diag_candidates -- SEED [small|5mp]`
use infraloc::camera::CameraModel;
use infraloc::config::{Config, GpsSourceKind};
use infraloc::localize::init::*;
use infraloc::localize::pipeline::Params;
use infraloc::sim::{self, Difficulty, Lens, Preset, Settings};
use rand::SeedableRng;

fn main() {
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
    })
    .unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let nmea = tmp.path().join("gps.nmea");
    std::fs::write(&nmea, &scene.nmea).unwrap();
    let mut g = Config::default().gps;
    g.source = GpsSourceKind::NmeaFile;
    g.path = Some(nmea);
    let (lat, lon, sigma) = infraloc::gps_serial::acquire_prior(&g)
        .unwrap()
        .position()
        .unwrap();
    let tile = &scene.tile;
    let prior = infraloc::geo::wgs84_to_map(tile.reflectivity.grid.crs, lat, lon).unwrap();
    let cam = &scene.camera_given;
    let (w, h) = scene.frame_size();
    let frames: Vec<image::GrayImage> = scene
        .frames
        .iter()
        .map(|f| image::GrayImage::from_raw(w, h, f.clone()).unwrap())
        .collect();
    let img = infraloc::capture::temporal_median(&frames).unwrap();
    let p = Params::default();
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
    let cands = coarse_candidates(cam, img.as_raw(), &tile.satellite, prior, radius, &p.coarse);
    println!(
        "sweep {:.1} s, {} candidates",
        t.elapsed().as_secs_f64(),
        cands.len()
    );
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(p.seed);
    let wrap = |a: f64| {
        (a + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI
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
        let t = std::time::Instant::now();
        match fine_stage(
            cam,
            img.as_raw(),
            &tile.satellite,
            &tile.height,
            prior,
            k,
            &p.fine,
            &mut rng,
        ) {
            Ok(f) => {
                let pc = f.pose.center();
                println!(
                    "pnp {}/{} rms {:.2} px: err {:.3} m z {:.3} yaw {:.2}° ({:.1} s)",
                    f.inliers,
                    f.matches,
                    f.rms_px,
                    (pc.x - c.x).hypot(pc.y - c.y),
                    pc.z - c.z,
                    wrap(f.pose.yaw_pitch_roll().0 - ty).to_degrees(),
                    t.elapsed().as_secs_f64()
                );
            }
            Err(e) => println!("pnp failed: {e}"),
        }
    }
    let _ = cam.width();
}
