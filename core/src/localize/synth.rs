//! Synthetic scenes for tests, benches and studies (pure maths, seeded): a procedural ground
//! texture, LiDAR points sampling it, and a fisheye image rendering it through a camera model.
//!
//! The image's gray is a *different*, non-monotonic function of the texture than the points'
//! reflectivity (plus independent noise on both), as between a camera and a LiDAR: MI has to find
//! the statistical dependence, not an equality.

use crate::camera::CameraModel;
use crate::localize::mi::points::GroundPoint;
use crate::pose::CamFromMap;
use nalgebra::{Point2, Point3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Value-noise lattice size (cells); the texture repeats after this many cells per octave.
const LATTICE: usize = 256;

/// A seeded procedural ground texture t(x, y) ∈ [0, 1]: three octaves of value noise (cells of
/// 2.5 m, 0.9 m, 0.35 m) plus painted lane lines (0.15 m wide every 3.5 m) and a crosswalk.
#[derive(Debug, Clone)]
pub struct Texture {
    table: Vec<f32>,
    angle: f64,
    /// Period (m) along map x and the y from which it applies, see [`Texture::repeating_x`].
    period_x: Option<(f64, f64)>,
}

impl Texture {
    /// A texture from a seed.
    pub fn new(seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let table = (0..LATTICE * LATTICE)
            .map(|_| rng.random::<f32>())
            .collect();
        Texture {
            table,
            angle: rng.random::<f64>() * std::f64::consts::PI,
            period_x: None,
        }
    }

    /// The same texture made to repeat every `period_m` metres along map x where y ≥ `from_y`:
    /// t(x, y) = t(x mod period, y) there, unchanged below. With `from_y` = −∞ a camera shifted
    /// by a whole period along x sees the same ground, so MI has equal peaks one period apart;
    /// with `from_y` through the camera's nadir only about half the ground repeats and the copies
    /// are lower peaks (tests of the quality gate's ambiguity rule). A non-finite or
    /// non-positive period leaves the texture as it is.
    pub fn repeating_x(mut self, period_m: f64, from_y: f64) -> Self {
        self.period_x = (period_m.is_finite() && period_m > 0.0).then_some((period_m, from_y));
        self
    }

    fn lattice(&self, i: i64, j: i64, octave: usize) -> f64 {
        let n = LATTICE as i64;
        let (a, b) = (
            (i + 17 * octave as i64).rem_euclid(n),
            (j + 31 * octave as i64).rem_euclid(n),
        );
        self.table[(a * n + b) as usize] as f64
    }

    fn noise(&self, x: f64, y: f64, cell: f64, octave: usize) -> f64 {
        let (fx, fy) = (x / cell, y / cell);
        let (i, j) = (fx.floor(), fy.floor());
        let (tx, ty) = (fx - i, fy - j);
        let s = |t: f64| t * t * (3.0 - 2.0 * t);
        let (sx, sy) = (s(tx), s(ty));
        let (i, j) = (i as i64, j as i64);
        let a = self.lattice(i, j, octave);
        let b = self.lattice(i + 1, j, octave);
        let c = self.lattice(i, j + 1, octave);
        let d = self.lattice(i + 1, j + 1, octave);
        a + (b - a) * sx + (c - a) * sy + (a - b - c + d) * sx * sy
    }

    /// Texture value at map (x, y).
    pub(crate) fn value(&self, x: f64, y: f64) -> f64 {
        let x = match self.period_x {
            Some((p, from_y)) if y >= from_y => x.rem_euclid(p),
            _ => x,
        };
        let n = 0.45 * self.noise(x, y, 2.5, 0)
            + 0.35 * self.noise(x, y, 0.9, 1)
            + 0.20 * self.noise(x, y, 0.35, 2);
        let (c, s) = (self.angle.cos(), self.angle.sin());
        let across = x * c + y * s;
        let along = -x * s + y * c;
        let lane = across.rem_euclid(3.5) < 0.15;
        let crosswalk = along.rem_euclid(12.0) < 2.5 && (across * 2.0).rem_euclid(1.2) < 0.5;
        if lane || crosswalk {
            0.95
        } else {
            0.8 * n
        }
    }

    /// LiDAR-like reflectivity of texture value t (monotonic).
    pub(crate) fn reflectivity(t: f64) -> f64 {
        255.0 * (0.1 + 0.8 * t)
    }

    /// Camera-like gray of texture value t (non-monotonic: dark asphalt and bright paint both map
    /// differently than in reflectivity).
    pub(crate) fn gray(t: f64) -> f64 {
        40.0 + 190.0 * (1.0 - (1.8 * t - 1.0).powi(2)).max(0.0) * 0.7 + 60.0 * t
    }
}

/// Ground points on a square grid of spacing `spacing` within `radius` of (cx, cy) at height z,
/// reflectivity from the texture plus Gaussian-ish noise of `noise` (0–255 units).
pub fn ground_points(
    tex: &Texture,
    center: (f64, f64),
    radius: f64,
    spacing: f64,
    z: f64,
    noise: f64,
    seed: u64,
) -> Vec<GroundPoint> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let k = (radius / spacing).floor() as i64;
    let mut out = Vec::new();
    for j in -k..=k {
        for i in -k..=k {
            let (dx, dy) = (i as f64 * spacing, j as f64 * spacing);
            if dx * dx + dy * dy > radius * radius {
                continue;
            }
            let (x, y) = (center.0 + dx, center.1 + dy);
            // Sum of 4 uniforms: cheap, seeded, roughly Gaussian with σ = noise.
            let e: f64 = (0..4).map(|_| rng.random::<f64>() - 0.5).sum::<f64>() * noise * 1.732;
            let r = (Texture::reflectivity(tex.value(x, y)) + e)
                .round()
                .clamp(0.0, 255.0);
            out.push(GroundPoint {
                x,
                y,
                z,
                reflectivity: r as u8,
            });
        }
    }
    out
}

/// The pose of a camera `height` metres above (x, y) = `center` looking along `heading`
/// (radians from north, clockwise), `down` radians below the horizon, image up = map up: a
/// vehicle's forward camera (`down` = 0) or a mast camera. (Roll 90° turns the north-up nadir
/// view of [`CamFromMap::from_center_ypr`] to look north; yaw is counter-clockwise, so the
/// clockwise heading enters negated.)
pub fn forward_view(center: (f64, f64), height: f64, heading: f64, down: f64) -> CamFromMap {
    CamFromMap::from_center_ypr(
        &Point3::new(center.0, center.1, height),
        -heading,
        0.0,
        std::f64::consts::FRAC_PI_2 - down,
    )
}

/// Ground returns of a spinning multi-beam LiDAR `lidar_h` metres above the plane z = 0 at
/// `center`, as a vehicle's scanner sees the road ahead: one ring per beam at elevations −24.8° to
/// −2° in 0.4° steps (a 64-beam scanner's lower block), 0.09° azimuth steps within ±50° of
/// `heading` (radians from north, clockwise). Rings are dense near the vehicle and metres apart
/// far out, unlike [`ground_points`]' uniform grid. Reflectivity from the texture plus noise of σ
/// ≈ 6 (0–255 units), seeded.
pub fn lidar_rings(
    tex: &Texture,
    center: (f64, f64),
    heading: f64,
    lidar_h: f64,
    seed: u64,
) -> Vec<GroundPoint> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut out = Vec::new();
    // Integer steps, so the rings and azimuths do not depend on accumulated rounding.
    for e in 0..=57 {
        let el = (24.8 - 0.4 * e as f64).to_radians();
        let d = lidar_h / el.tan();
        for k in 0..=1111 {
            let a = heading + (-50.0 + 0.09 * k as f64).to_radians();
            let (x, y) = (center.0 + d * a.sin(), center.1 + d * a.cos());
            let noise: f64 = (0..4).map(|_| rng.random::<f64>() - 0.5).sum::<f64>() * 6.0;
            let r = (Texture::reflectivity(tex.value(x, y)) + noise)
                .round()
                .clamp(0.0, 255.0);
            out.push(GroundPoint {
                x,
                y,
                z: 0.0,
                reflectivity: r as u8,
            });
        }
    }
    out
}

/// Render the ground plane z = `ground_z` through `cam` at `pose`: 2×2 supersampled texture →
/// `Texture::gray` + noise of `noise` gray levels. Pixels outside the valid image circle are 0;
/// rays above the horizon see a uniform sky (gray 210). Returns (gray, valid mask).
pub fn render(
    tex: &Texture,
    cam: &dyn CameraModel,
    pose: &CamFromMap,
    ground_z: f64,
    noise: f64,
    seed: u64,
) -> (Vec<u8>, Vec<u8>) {
    let (w, h) = (cam.width() as usize, cam.height() as usize);
    let mask = cam.valid_mask();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let c = pose.center();
    let r_mfc = pose.rotation.inverse();
    let mut gray = vec![0u8; w * h];
    const SKY: f64 = 210.0;
    for v in 0..h {
        for u in 0..w {
            if mask[v * w + u] == 0 {
                continue;
            }
            let mut acc = 0.0;
            for (du, dv) in [(-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25)] {
                let px = Point2::new(u as f64 + du, v as f64 + dv);
                acc += match cam.unproject(&px) {
                    Ok(ray) => {
                        let d = r_mfc * ray.into_inner();
                        if d.z < -1e-6 {
                            let s = (ground_z - c.z) / d.z;
                            let p: Point3<f64> = c + d * s;
                            Texture::gray(tex.value(p.x, p.y))
                        } else {
                            SKY
                        }
                    }
                    Err(_) => SKY,
                };
            }
            let e: f64 = (0..4).map(|_| rng.random::<f64>() - 0.5).sum::<f64>() * noise * 1.732;
            gray[v * w + u] = (acc / 4.0 + e).round().clamp(0.0, 255.0) as u8;
        }
    }
    (gray, mask)
}
