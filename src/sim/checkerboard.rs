//! Rendered fisheye views of a planar checkerboard, for calibration tests and
//! `infraloc simulate --checkerboard N` (docs/calibrate.md, "Simulated boards"). Pure: camera and
//! seed in, 8-bit images and the true corner pixels out.
//!
//! Each pixel is ray-cast through the true camera onto the board plane. A pixel whose four corner
//! rays land in one board square (or all miss the board) is uniform, because a square is convex;
//! every other pixel is supersampled on a [`SUPERSAMPLE`]² grid, so edges are anti-aliased exactly
//! where they cross. The rays of the pixel corners are computed once per camera (the unprojection
//! is the expensive part) and bilinearly interpolated inside a pixel, an error far below 0.001 px
//! for a smooth lens. Then a slight optical blur and signal-dependent sensor noise, drawn from
//! counter-based hashes so rows render in parallel and the output is the same for a seed.

use super::noise::{gauss, hash3, mix64};
use super::render::gaussian_blur;
use crate::camera::{Camera, CameraModel};
use nalgebra::{Point2, Rotation3, Unit, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use std::f64::consts::TAU;

/// Sub-samples per side of an edge pixel.
pub const SUPERSAMPLE: usize = 4;
/// Intensity of the black squares (linear, 0–1).
const BLACK: f32 = 0.08;
/// Intensity of the white squares and the board's margin.
const WHITE: f32 = 0.86;
/// Optical blur (Gaussian σ, px): a real lens is never sharper than a pixel.
const BLUR_SIGMA: f64 = 0.6;
/// Read noise, 8-bit levels (σ).
const READ_NOISE_DN: f64 = 1.5;
/// Shot noise: variance per level of signal.
const SHOT_NOISE_PER_DN: f64 = 0.04;

/// A checkerboard: `cols × rows` inner corners (OpenCV's pattern size), squares of `square`
/// metres, and one square's width of white margin around the outer squares.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Board {
    /// Inner corners along a row.
    pub cols: usize,
    /// Inner corners along a column.
    pub rows: usize,
    /// Side of a square, metres.
    pub square: f64,
}

impl Board {
    /// Board-frame position of inner corner `(i, j)` (`i` along a row): `(i·s, j·s, 0)`.
    pub fn corner(&self, i: usize, j: usize) -> [f64; 3] {
        [i as f64 * self.square, j as f64 * self.square, 0.0]
    }

    /// All inner corners, row by row (the order `--corners` files and the detector use).
    pub fn corners(&self) -> Vec<[f64; 3]> {
        (0..self.rows)
            .flat_map(|j| (0..self.cols).map(move |i| (i, j)))
            .map(|(i, j)| self.corner(i, j))
            .collect()
    }

    /// Square index and colour at board-frame `(x, y)`: `None` off the paper, `Some((key,
    /// intensity))` on it, where `key` is the same for all points of one square (the margin is
    /// one key).
    fn shade(&self, x: f64, y: f64) -> Option<(i64, f32)> {
        let s = self.square;
        let (cx, cy) = ((x / s).floor(), (y / s).floor());
        let (nc, nr) = (self.cols as f64, self.rows as f64);
        if cx < -2.0 || cy < -2.0 || cx > nc || cy > nr {
            return None;
        }
        if cx < -1.0 || cy < -1.0 || cx >= nc || cy >= nr {
            return Some((i64::MIN, WHITE));
        }
        let key = (cy as i64 + 1) * (self.cols as i64 + 2) + cx as i64 + 1;
        // The square left of and above corner (0, 0) is black.
        let black = (cx as i64 + cy as i64).rem_euclid(2) == 0;
        Some((key, if black { BLACK } else { WHITE }))
    }
}

/// Board pose: camera point = `r`·board point + `t`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoardPose {
    /// Rotation board → camera.
    pub r: Rotation3<f64>,
    /// Translation, metres.
    pub t: Vector3<f64>,
}

/// One rendered view.
#[derive(Debug, Clone)]
pub struct BoardView {
    /// The board's pose.
    pub pose: BoardPose,
    /// True pixel of every inner corner (row by row, as [`Board::corners`]); `None` where the
    /// corner is outside the image or the lens's field of view.
    pub corners: Vec<Option<[f64; 2]>>,
    /// The 8-bit grey image, row-major.
    pub image: Vec<u8>,
}

/// Rays of the pixel corners: entry `(i, j)` is the unit ray of image point `(i − ½, j − ½)`,
/// `None` outside the lens's field of view or where the model has no inverse.
struct RayGrid {
    w: usize,
    rays: Vec<Option<[f32; 3]>>,
}

impl RayGrid {
    fn new(cam: &Camera) -> RayGrid {
        let (w, h) = (cam.width() as usize + 1, cam.height() as usize + 1);
        let max_theta = cam.max_theta();
        let rays = (0..h)
            .into_par_iter()
            .flat_map_iter(|j| {
                (0..w).map(move |i| {
                    let px = Point2::new(i as f64 - 0.5, j as f64 - 0.5);
                    cam.unproject(&px)
                        .ok()
                        .filter(|r| r.z.clamp(-1.0, 1.0).acos() <= max_theta)
                        .map(|r| [r.x as f32, r.y as f32, r.z as f32])
                })
            })
            .collect();
        RayGrid { w, rays }
    }

    fn at(&self, i: usize, j: usize) -> Option<[f32; 3]> {
        self.rays[j * self.w + i]
    }
}

/// The board plane in the camera frame, for ray casting.
struct Plane {
    n: Vector3<f64>,
    d: f64,
    ex: Vector3<f64>,
    ey: Vector3<f64>,
    t: Vector3<f64>,
}

impl Plane {
    fn new(p: &BoardPose) -> Plane {
        let n = p.r * Vector3::z();
        Plane {
            n,
            d: n.dot(&p.t),
            ex: p.r * Vector3::x(),
            ey: p.r * Vector3::y(),
            t: p.t,
        }
    }

    /// Board-frame (x, y) where the ray meets the plane in front of the camera.
    fn hit(&self, ray: Vector3<f64>) -> Option<(f64, f64)> {
        let den = self.n.dot(&ray);
        if den.abs() < 1e-12 {
            return None;
        }
        let lambda = self.d / den;
        if !(lambda > 0.0) {
            return None;
        }
        let q = ray * lambda - self.t;
        Some((self.ex.dot(&q), self.ey.dot(&q)))
    }
}

/// Grey level of the background seen along a ray: a smooth wall-like gradient, darker than the
/// white squares so the board's margin stands out.
fn background(ray: Vector3<f64>) -> f32 {
    (0.38 + 0.12 * ray.y + 0.06 * (3.0 * ray.x).sin()) as f32
}

/// Render one view (linear intensities, before blur and noise).
fn render_linear(
    cam: &Camera,
    grid: &RayGrid,
    board: &Board,
    pose: &BoardPose,
    gain: f32,
) -> Vec<f32> {
    let (w, h) = (cam.width() as usize, cam.height() as usize);
    let plane = Plane::new(pose);
    let shade = |ray: Vector3<f64>| -> (Option<i64>, f32) {
        match plane.hit(ray).and_then(|(x, y)| board.shade(x, y)) {
            Some((k, v)) => (Some(k), v * gain),
            None => (None, background(ray)),
        }
    };
    let mut out = vec![0.0f32; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(j, row)| {
        // Keys of this row's pixel corners, top and bottom edge.
        let key_at = |i: usize, jj: usize| -> Option<Option<i64>> {
            grid.at(i, jj)
                .map(|r| shade(Vector3::new(r[0] as f64, r[1] as f64, r[2] as f64)).0)
        };
        let top: Vec<Option<Option<i64>>> = (0..=w).map(|i| key_at(i, j)).collect();
        let bottom: Vec<Option<Option<i64>>> = (0..=w).map(|i| key_at(i, j + 1)).collect();
        for (i, o) in row.iter_mut().enumerate() {
            let keys = [top[i], top[i + 1], bottom[i], bottom[i + 1]];
            // Outside the image circle: black (the lens's rim).
            let (Some(k00), Some(k10), Some(k01), Some(k11)) = (keys[0], keys[1], keys[2], keys[3])
            else {
                *o = 0.0;
                continue;
            };
            let c = [
                grid.at(i, j).unwrap_or_default(),
                grid.at(i + 1, j).unwrap_or_default(),
                grid.at(i, j + 1).unwrap_or_default(),
                grid.at(i + 1, j + 1).unwrap_or_default(),
            ];
            let ray_at = |a: f64, b: f64| -> Vector3<f64> {
                let v = |k: usize| {
                    (1.0 - b) * ((1.0 - a) * c[0][k] as f64 + a * c[1][k] as f64)
                        + b * ((1.0 - a) * c[2][k] as f64 + a * c[3][k] as f64)
                };
                Vector3::new(v(0), v(1), v(2))
            };
            if k00 == k10 && k00 == k01 && k00 == k11 && k00.is_some() {
                // One convex square covers the pixel.
                *o = shade(ray_at(0.5, 0.5)).1;
                continue;
            }
            let mut sum = 0.0f32;
            for sb in 0..SUPERSAMPLE {
                for sa in 0..SUPERSAMPLE {
                    let a = (sa as f64 + 0.5) / SUPERSAMPLE as f64;
                    let b = (sb as f64 + 0.5) / SUPERSAMPLE as f64;
                    sum += shade(ray_at(a, b)).1;
                }
            }
            *o = sum / (SUPERSAMPLE * SUPERSAMPLE) as f32;
        }
    });
    out
}

/// Board poses for `n` views: centres spread over the field of view (stratified in angle from
/// the axis and in azimuth, some near the lens edge), tilted 10–55°, turned in-plane at random,
/// and every fifth view pushed past the field's edge so the board is only partly in the image.
pub fn poses(cam: &Camera, board: &Board, n: usize, seed: u64) -> Vec<BoardPose> {
    let mut rng = ChaCha8Rng::seed_from_u64(mix64(seed ^ 0xB0A2_D5EE_D000_0001));
    // The field the sensor sees: largest angle from the axis with a pixel on the sensor, sampled
    // along the borders (the sensor may crop the image circle).
    let (w, h) = (cam.width() as f64, cam.height() as f64);
    let mut edge = 0.0f64;
    for k in 0..64 {
        let s = k as f64 / 63.0;
        for px in [
            Point2::new(s * (w - 1.0), 0.0),
            Point2::new(s * (w - 1.0), h - 1.0),
            Point2::new(0.0, s * (h - 1.0)),
            Point2::new(w - 1.0, s * (h - 1.0)),
        ] {
            if let Ok(r) = cam.unproject(&px) {
                edge = edge.max(r.z.clamp(-1.0, 1.0).acos());
            }
        }
    }
    let edge = edge.min(cam.max_theta()).max(0.3);
    let centre = Vector3::new(
        (board.cols as f64 - 1.0) * board.square / 2.0,
        (board.rows as f64 - 1.0) * board.square / 2.0,
        0.0,
    );
    let diag = ((board.cols + 1) as f64).hypot((board.rows + 1) as f64) * board.square;
    let az0 = rng.random_range(0.0..TAU);
    (0..n)
        .map(|k| {
            let partial = k % 5 == 4;
            let frac = (k as f64 + rng.random_range(0.2..0.8)) / n as f64;
            // Angle of the board's centre from the axis: most of the board inside the field.
            let theta = if partial {
                edge * rng.random_range(0.92..1.0)
            } else {
                edge * rng.random_range(0.0..0.72f64).max(frac.sqrt() * 0.72)
            };
            let az = az0 + k as f64 * 2.399_963 + rng.random_range(-0.3..0.3);
            let dir = Vector3::new(theta.sin() * az.cos(), theta.sin() * az.sin(), theta.cos());
            // Angular size of the board's diagonal.
            let size = rng.random_range(60f64..95.0).to_radians();
            let dist = diag / 2.0 / (size / 2.0).tan();
            // Facing the camera, then tilted about an axis across the line of sight.
            let facing = -dir;
            let across = Unit::new_normalize(
                dir.cross(&Vector3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                )) + Vector3::new(1e-9, 0.0, 0.0),
            );
            let tilt = rng.random_range(10f64..55.0).to_radians();
            let normal = Rotation3::from_axis_angle(&across, tilt) * facing;
            let helper = if normal.x.abs() < 0.9 {
                Vector3::x()
            } else {
                Vector3::y()
            };
            let ex0 = (helper - normal * normal.dot(&helper)).normalize();
            let spin = rng.random_range(0.0..TAU);
            let ex = Rotation3::from_axis_angle(&Unit::new_normalize(normal), spin) * ex0;
            let ey = normal.cross(&ex);
            let r = Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_columns(&[
                ex, ey, normal,
            ]));
            let t = dir * dist - r * centre;
            BoardPose { r, t }
        })
        .collect()
}

/// Render `n` views of `board` seen by `cam` (poses from [`poses`]), deterministic for a seed.
pub fn render(cam: &Camera, board: &Board, n: usize, seed: u64) -> Vec<BoardView> {
    let grid = RayGrid::new(cam);
    let (w, h) = (cam.width() as usize, cam.height() as usize);
    let cos_max_theta = cam.max_theta().cos();
    poses(cam, board, n, seed)
        .into_iter()
        .enumerate()
        .map(|(k, pose)| {
            let vseed = mix64(seed ^ mix64(k as u64 + 1));
            let gain = 0.75 + 0.25 * super::noise::unit(vseed) as f32;
            let mut lin = render_linear(cam, &grid, board, &pose, gain);
            gaussian_blur(&mut lin, w, h, BLUR_SIGMA);
            let mut image = vec![0u8; w * h];
            image.par_chunks_mut(w).enumerate().for_each(|(j, row)| {
                for (i, o) in row.iter_mut().enumerate() {
                    let dn = lin[j * w + i] as f64 * 255.0;
                    let sigma = (READ_NOISE_DN * READ_NOISE_DN + SHOT_NOISE_PER_DN * dn).sqrt();
                    let v = dn + sigma * gauss(hash3(vseed, i as i64, j as i64));
                    *o = v.round().clamp(0.0, 255.0) as u8;
                }
            });
            let corners = board
                .corners()
                .iter()
                .map(|x| {
                    let pc = pose.r * Vector3::new(x[0], x[1], x[2]) + pose.t;
                    cam.project_visible_cos(&pc, cos_max_theta)
                        .ok()
                        .map(|p| [p.x, p.y])
                })
                .collect();
            BoardView {
                pose,
                corners,
                image,
            }
        })
        .collect()
}

/// The calibration's corner detector on boards this module renders (the core cannot depend on
/// the simulator, so the detector's rendered-board tests live here).
#[cfg(test)]
mod detect_tests {
    use super::{render, Board};
    use crate::calib::detect::*;
    use crate::camera::{Camera, Mei};

    fn camera() -> Camera {
        Camera::Mei(Mei {
            width: 640,
            height: 480,
            fx: 400.0,
            fy: 400.5,
            cx: 321.0,
            cy: 238.5,
            skew: 0.0,
            xi: 1.6,
            k1: -0.02,
            k2: 0.004,
            p1: 0.0,
            p2: 0.0,
            fov_deg: Some(185.0),
        })
    }

    /// Detected corners against the renderer's truth: every corner of the full boards, within
    /// 0.25 px, 0.08 px RMS; the labels are a 9×6 grid of the square.
    #[test]
    fn finds_rendered_boards_to_a_tenth_of_a_pixel() {
        let cam = camera();
        let board = Board {
            cols: 9,
            rows: 6,
            square: 0.03,
        };
        let views = render(&cam, &board, 4, 11);
        let (mut ss, mut n) = (0.0, 0usize);
        for (k, v) in views.iter().enumerate() {
            let truth: Vec<[f64; 2]> = v.corners.iter().flatten().copied().collect();
            let found = detect(&v.image, 640, 480, 9, 6, 0.03);
            if k % 5 == 4 || truth.len() < 54 {
                continue;
            }
            let f = found.unwrap_or_else(|e| panic!("view {k}: {e}"));
            assert!(f.full && f.image.len() == 54, "view {k}: {}", f.image.len());
            for o in &f.object {
                let (i, j) = (o[0] / 0.03, o[1] / 0.03);
                assert!((i - i.round()).abs() < 1e-9 && (j - j.round()).abs() < 1e-9);
                assert!(i.round() < 9.0 && j.round() < 6.0);
            }
            for p in &f.image {
                let d = truth
                    .iter()
                    .map(|t| (t[0] - p[0]).hypot(t[1] - p[1]))
                    .fold(f64::MAX, f64::min);
                assert!(d < 0.25, "view {k}: corner at {p:?} is {d} px off");
                ss += d * d;
                n += 1;
            }
        }
        assert!(n >= 3 * 54, "{n} corners checked");
        let rms = (ss / n as f64).sqrt();
        assert!(rms < 0.08, "RMS {rms}");
    }

    #[test]
    fn a_grid_larger_than_the_pattern_or_no_board_is_refused_with_a_reason() {
        let cam = camera();
        let board = Board {
            cols: 9,
            rows: 6,
            square: 0.03,
        };
        let v = &render(&cam, &board, 1, 11)[0];
        let err = detect(&v.image, 640, 480, 6, 4, 0.03)
            .unwrap_err()
            .to_string();
        assert!(err.contains("larger than the 6×4 pattern"), "{err}");
        let grey = vec![100u8; 640 * 480];
        let err = detect(&grey, 640, 480, 9, 6, 0.03).unwrap_err().to_string();
        assert_eq!(err, "no corner-like points");
        assert!(detect(&grey, 640, 10, 9, 6, 0.03).is_err());
    }
}
