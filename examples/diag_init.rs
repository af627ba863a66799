//! Diagnostic: coarse candidates and fine-stage match counts of the initializer on a scene dir.
//! `cargo run --release --example diag_init -- SCENE_DIR`
use infraloc::camera::{load_camera, CameraModel};
use infraloc::localize::frame::{Frame, MapLayers};
use infraloc::localize::init::coarse::*;
use infraloc::localize::init::ground::*;
use infraloc::localize::init::*;
fn main() {
    let dir = std::path::PathBuf::from(std::env::args().nth(1).expect("scene dir"));
    let cam = load_camera(&dir.join("camera.yaml")).unwrap();
    let img = image::open(dir.join("frames/000.png")).unwrap().to_luma8();
    let truth = infraloc::posefile::read_pose(&dir.join("truth.json"))
        .unwrap()
        .pose;
    let tdir = std::fs::read_dir(dir.join("tiles"))
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    let tile = infraloc::map::cache::load_tile(&tdir).unwrap();
    let satellite = tile
        .satellite
        .as_ref()
        .expect("the tile has a satellite layer");
    let c = truth.center();
    let (y, p, r) = truth.yaw_pitch_roll();
    let zg = height_at(&tile.height, c.x, c.y).unwrap();
    println!(
        "truth centre {:?} yaw {:.2} pitch {:.2} roll {:.2} height above ground {:.2}",
        c,
        y.to_degrees(),
        p.to_degrees(),
        r.to_degrees(),
        c.z - zg
    );
    let prior = (c.x + 4.0, c.y - 3.0);
    let t = std::time::Instant::now();
    let cands = coarse_candidates(
        &cam,
        img.as_raw(),
        satellite,
        prior,
        15.0,
        &CoarseParams::default(),
    );
    println!("coarse {:.2} s", t.elapsed().as_secs_f64());
    for k in &cands {
        println!(
            "  yaw {:7.2} h {:5.2} pos ({:8.2},{:8.2}) err ({:6.2},{:6.2}) score {:.3}",
            k.yaw.to_degrees(),
            k.height,
            prior.0 + k.offset[0],
            prior.1 + k.offset[1],
            prior.0 + k.offset[0] - c.x,
            prior.1 + k.offset[1] - c.y,
            k.score
        );
    }
    // Fine stage from the truth-perturbed pose.
    let fine = FineParams::default();
    let start0 = infraloc::pose::CamFromMap::from_center_ypr(
        &nalgebra::Point3::new(c.x + 0.5, c.y - 0.4, c.z + 0.3),
        y + 0.03,
        0.0,
        0.0,
    );
    for (label, start) in [("truth", truth), ("perturbed", start0)] {
        for &(ph, sh, res, _) in &fine.iterations {
            let m = match_anchors(
                &cam,
                img.as_raw(),
                satellite,
                &tile.height,
                &start,
                (ph, sh, res),
                &fine,
            );
            let inv = truth.inverse();
            let errs: Vec<f64> = m
                .iter()
                .map(|a| {
                    let b = cam.unproject(&a.corr.pixel).unwrap().into_inner();
                    let d = inv.rotate(&b);
                    let t = (a.corr.world.z - c.z) / d.z;
                    ((c.x + t * d.x - a.corr.world.x).powi(2)
                        + (c.y + t * d.y - a.corr.world.y).powi(2))
                    .sqrt()
                })
                .collect();
            let good = errs.iter().filter(|e| **e < 0.5).count();
            let mut se = errs.clone();
            se.sort_by(f64::total_cmp);
            println!(
                "  median metric err {:.2} m",
                se.get(se.len() / 2).copied().unwrap_or(f64::NAN)
            );
            let shifts: Vec<String> = m
                .iter()
                .take(8)
                .map(|a| format!("{:.2}", a.score))
                .collect();
            println!(
                "{label} fine ({ph},{sh},{res}): {} matches, {} within 0.5 m of truth; scores {:?}",
                m.len(),
                good,
                shifts
            );
        }
    }
    let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(0);
    let r = initialize(
        &Frame::new(&cam, img.as_raw()).unwrap(),
        MapLayers {
            satellite,
            heights: &tile.height,
        },
        SearchArea {
            center: prior,
            radius_m: 15.0,
        },
        &CoarseParams::default(),
        &FineParams::default(),
        None,
        &mut rng,
    )
    .unwrap();
    let pc = r.pose.center();
    let (py, pp, pr) = r.pose.yaw_pitch_roll();
    println!("init: err ({:.3},{:.3},{:.3}) m yaw {:.2} pitch {:.2} roll {:.2} deg; inliers {}/{} rms {:.1}px cand yaw {:.1} h {:.2}", pc.x-c.x, pc.y-c.y, pc.z-c.z, (py-y).to_degrees(), (pp-p).to_degrees(), (pr - r_true(&truth)).to_degrees(), r.inliers, r.matches, r.rms_px, r.candidate.yaw.to_degrees(), r.candidate.height);
}
fn r_true(t: &infraloc::pose::CamFromMap) -> f64 {
    t.yaw_pitch_roll().2
}
