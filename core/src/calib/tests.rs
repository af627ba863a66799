use super::*;
use crate::camera::{Equidistant, Mei};
use nalgebra::{Rotation3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A 9×6 grid of 5 cm squares, as OpenCV lists a board (row by row, z = 0).
fn board() -> Vec<[f64; 3]> {
    grid(9, 6, 0.05)
}

/// `cols`×`rows` inner corners, `square` apart.
fn grid(cols: usize, rows: usize, square: f64) -> Vec<[f64; 3]> {
    (0..rows)
        .flat_map(|r| (0..cols).map(move |c| [c as f64 * square, r as f64 * square, 0.0]))
        .collect()
}

/// `n` views of the board spread over the field, tilted 15–50°, noise σ px.
fn views(cam: &Camera, n: usize, sigma: f64, seed: u64) -> Observations {
    views_and_rays(cam, n, sigma, seed).0
}

/// [`views`] and the camera-frame rays of all their corners (the field the boards cover).
fn views_and_rays(
    cam: &Camera,
    n: usize,
    sigma: f64,
    seed: u64,
) -> (Observations, Vec<Vector3<f64>>) {
    board_views(cam, &board(), n, sigma, seed)
}

/// [`views_and_rays`] of any board.
fn board_views(
    cam: &Camera,
    obj: &[[f64; 3]],
    n: usize,
    sigma: f64,
    seed: u64,
) -> (Observations, Vec<Vector3<f64>>) {
    let mut rays = Vec::new();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
    for x in obj {
        for k in 0..2 {
            lo[k] = lo[k].min(x[k]);
            hi[k] = hi[k].max(x[k]);
        }
    }
    let mut out = Vec::new();
    while out.len() < n {
        // Board centre direction: up to 75° off axis, at 0.25–0.5 m.
        let th = rng.random_range(0.0..75f64).to_radians();
        let az = rng.random_range(0.0..std::f64::consts::TAU);
        let dir = Vector3::new(th.sin() * az.cos(), th.sin() * az.sin(), th.cos());
        let dist = rng.random_range(0.25..0.5);
        // Board faces the camera, then tilted.
        let face =
            Rotation3::rotation_between(&Vector3::z(), &dir).unwrap_or(Rotation3::identity());
        let tilt = Rotation3::from_euler_angles(
            rng.random_range(-0.8..0.8),
            rng.random_range(-0.8..0.8),
            rng.random_range(-3.0..3.0),
        );
        let r = face * tilt;
        let centre = Vector3::new((lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0, 0.0);
        let t = dir * dist - r * centre;
        let mut image = Vec::new();
        let mut seen = Vec::new();
        let mut ok = true;
        for x in obj {
            let xc = r * Vector3::new(x[0], x[1], x[2]) + t;
            seen.push(xc);
            match cam.project_visible(&xc) {
                Ok(p) => image.push([p.x + sigma * gauss(&mut rng), p.y + sigma * gauss(&mut rng)]),
                Err(_) => ok = false,
            }
        }
        if ok
            && image.iter().all(|p| {
                p[0] > 0.0
                    && p[1] > 0.0
                    && p[0] < cam.width() as f64 - 1.0
                    && p[1] < cam.height() as f64 - 1.0
            })
        {
            out.push(View {
                name: format!("view {}", out.len()),
                object: obj.to_vec(),
                image,
            });
            rays.extend(seen);
        }
    }
    let obs = Observations {
        width: cam.width(),
        height: cam.height(),
        views: out,
    };
    (obs, rays)
}

fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = rng.random_range(1e-12..1.0);
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// Max and mean pixel distance between the two cameras' projections of `rays`.
fn mapping_error(truth: &Camera, fit: &Camera, rays: &[Vector3<f64>]) -> (f64, f64) {
    let (mut max, mut sum) = (0.0f64, 0.0);
    for ray in rays {
        let d = (truth.project(ray).unwrap() - fit.project(ray).unwrap()).norm();
        max = max.max(d);
        sum += d;
    }
    (max, sum / rays.len() as f64)
}

/// Rays on a grid of θ ≤ `max_theta`.
fn field(max_theta: f64) -> Vec<Vector3<f64>> {
    (0..40)
        .flat_map(|i| {
            let th = max_theta * (i as f64 + 0.5) / 40.0;
            (0..36).map(move |j| {
                let az = j as f64 * 10f64.to_radians();
                Vector3::new(th.sin() * az.cos(), th.sin() * az.sin(), th.cos())
            })
        })
        .collect()
}

fn mei(xi: f64) -> Camera {
    Camera::Mei(Mei {
        width: 1024,
        height: 1024,
        fx: 300.0 * (1.0 + xi),
        fy: 300.5 * (1.0 + xi),
        cx: 515.0,
        cy: 508.0,
        skew: 0.0,
        xi,
        k1: -0.05,
        k2: 0.01,
        p1: 1e-4,
        p2: -1e-4,
        fov_deg: Some(185.0),
    })
}

#[test]
fn noise_free_mei_is_recovered_exactly() {
    let truth = mei(1.2);
    let obs = views(&truth, 12, 0.0, 1);
    let c = calibrate(&obs, LensModel::Mei).unwrap();
    assert!(c.rms < 1e-6, "rms {}", c.rms);
    let (max, _) = mapping_error(&truth, &c.camera, &field(80f64.to_radians()));
    assert!(max < 1e-4, "mapping max {max}");
    assert!(c.views.iter().all(|v| v.used));
}

#[test]
fn noisy_mei_and_equidistant_map_like_the_truth() {
    let equi = Camera::Equidistant(Equidistant {
        width: 1024,
        height: 1024,
        fx: 300.0,
        fy: 300.2,
        cx: 509.0,
        cy: 516.0,
        alpha: 0.0,
        k1: -0.01,
        k2: 0.001,
        k3: -2e-4,
        k4: 2e-5,
        fov_deg: Some(185.0),
        cache: Default::default(),
    });
    for (truth, model) in [
        (mei(0.8), LensModel::Mei),
        (mei(2.2), LensModel::Mei),
        (equi, LensModel::Equidistant),
    ] {
        let (obs, rays) = board_views(&truth, &grid(11, 8, 0.04), 20, 0.05, 7);
        let c = calibrate(&obs, model).unwrap();
        // σ = 0.05 px per coordinate: RMS of the 2-D error ≈ 0.05·√2.
        assert!(
            (c.rms - 0.05 * 2f64.sqrt()).abs() < 0.01,
            "{model:?} rms {}",
            c.rms
        );
        let (max, mean) = mapping_error(&truth, &c.camera, &rays);
        assert!(
            mean < 0.15 && max < 0.4,
            "{model:?} mapping mean {mean} max {max}"
        );
        assert!(c.params.iter().all(|p| p.std.is_finite() && p.std > 0.0));
    }
}

#[test]
fn an_outlier_view_is_removed_and_named() {
    let truth = mei(1.0);
    let mut obs = views(&truth, 10, 0.1, 3);
    // View 4's detections with a wrong corner ordering: its first two rows swapped.
    let img = &mut obs.views[4].image;
    let (row0, rest) = img.split_at_mut(9);
    row0.swap_with_slice(&mut rest[..9]);
    let c = calibrate(&obs, LensModel::Mei).unwrap();
    let v4 = &c.views[4];
    assert!(!v4.used);
    assert!(
        v4.rejected.as_deref().unwrap_or("").starts_with("outlier"),
        "{v4:?}"
    );
    assert_eq!(c.views.iter().filter(|v| v.used).count(), 9);
    assert!(c.rms < 0.15, "{}", c.rms);
}

#[test]
fn bad_input_is_one_line_naming_the_view() {
    let truth = mei(1.0);
    let good = views(&truth, 5, 0.1, 5);
    let msg = |o: &Observations| calibrate(o, LensModel::Mei).unwrap_err().to_string();

    let mut o = good.clone();
    o.views.truncate(2);
    assert_eq!(msg(&o), "2 usable view(s), need at least 3");

    let mut o = good.clone();
    o.views.clear();
    assert_eq!(msg(&o), "no board found in any view");

    let mut o = good.clone();
    o.views[1].image.pop();
    assert_eq!(msg(&o), "view 1: 54 object points but 53 image points");

    let mut o = good.clone();
    o.views[2].image[7] = [1030.0, 20.0];
    assert_eq!(
        msg(&o),
        "view 2: corner 7 at (1030.0, 20.0) lies outside the 1024×1024 image"
    );

    let mut o = good.clone();
    o.views[3].object[10][2] = 0.01;
    assert!(msg(&o).starts_with("view 3: the object points are not planar"));

    // Fronto-parallel boards straight ahead at different distances and offsets.
    let obj = board();
    let fronto: Vec<View> = (0..4)
        .map(|i| {
            let t = Vector3::new(-0.2 + 0.05 * i as f64, -0.1, 0.3 + 0.1 * i as f64);
            View {
                name: format!("view {i}"),
                object: obj.clone(),
                image: obj
                    .iter()
                    .map(|x| {
                        let p = truth
                            .project(&(Vector3::new(x[0], x[1], x[2]) + t))
                            .unwrap();
                        [p.x, p.y]
                    })
                    .collect(),
            }
        })
        .collect();
    let o = Observations {
        width: 1024,
        height: 1024,
        views: fronto,
    };
    let m = msg(&o);
    assert!(
        m.starts_with("degenerate views: all 4 boards are fronto-parallel"),
        "{m}"
    );
}
