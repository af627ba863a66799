//! Ray casting shared by all simulated sensors, and the fisheye camera.
//!
//! The fisheye frame is rendered by casting one ray per pixel: `CameraModel::unproject` gives the
//! bearing in the camera frame, the *inverse* of the true pose turns it into a map-frame ray from
//! the camera centre, and the ray is intersected with the height field (not a plane) and every
//! solid. What the camera sees at that point is then lit by its own sun and sky, shadowed by the
//! solids, and passed through a sensor model (optical blur, vignetting, exposure, shot and read
//! noise, gamma, 8-bit quantisation).
//!
//! Static content (ground, buildings, trees, parked cars) is the same in every frame, so it is cast
//! once ([`StaticPass`]); each frame then only tests its moving vehicles and pedestrians (which can
//! occlude the static hit or shadow it).

use super::appearance::Appearance;
use super::noise::{gauss, hash3, Field};
use super::solids::{nearest, Hit, Kind, Solid};
use super::world::{World, DETAIL_MAX, DETAIL_MIN};
use crate::camera::{Camera, CameraModel};
pub(crate) use crate::imageops::gaussian_blur;
use crate::pose::CamFromMap;
use nalgebra::{Point2, Vector3};
use rayon::prelude::*;

/// Rays that would meet the ground further than this are treated as seeing the horizon, metres.
const MAX_GROUND_RANGE: f64 = 5000.0;
/// Horizontal step of the fallback ground march (curb faces are 2 cm wide ramps), metres.
const MARCH_STEP: f64 = 0.01;
/// Maximum steps of the fallback march.
const MARCH_MAX_STEPS: usize = 3000;
/// Finite-difference step for ground normals, metres.
const NORMAL_EPS: f64 = 0.01;
/// Fraction of sunlight a tree crown lets through (average; dappled by noise).
const CROWN_TRANSMIT: f64 = 0.22;

/// Sun and sky of one sensor's acquisition.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Light {
    /// Unit vector towards the sun (map frame).
    pub sun: Vector3<f64>,
    /// Direct irradiance on a surface facing the sun (0 = overcast).
    pub sun_irr: f64,
    /// Diffuse sky irradiance on a horizontal surface.
    pub ambient: f64,
}

impl Light {
    /// Sun from azimuth (clockwise from north) and elevation, degrees.
    pub(crate) fn from_az_el(az_deg: f64, el_deg: f64, sun_irr: f64, ambient: f64) -> Self {
        let (az, el) = (az_deg.to_radians(), el_deg.to_radians());
        Light {
            sun: Vector3::new(az.sin() * el.cos(), az.cos() * el.cos(), el.sin()),
            sun_irr,
            ambient,
        }
    }
}

/// First intersection of the ray `o + t·d` (d unit) with the ground height field, if any.
///
/// The ground lies within [`DETAIL_MIN`, `DETAIL_MAX`] of the sloped base plane, which brackets
/// the hit in `[t_top, t_bot]`. A secant iteration finds it where the ground is smooth; near a curb
/// (where the ray could meet the step's face first) or if the secant fails, a fine march from
/// `t_top` followed by bisection finds the *first* crossing.
pub(crate) fn intersect_ground(w: &World, o: &Vector3<f64>, d: &Vector3<f64>) -> Option<f64> {
    let g0 = o.z - w.base(o.x, o.y);
    let g1 = d.z - w.grad[0] * d.x - w.grad[1] * d.y;
    if g1 >= -1e-12 {
        return None;
    }
    let t_top = ((DETAIL_MAX - g0) / g1).max(0.0);
    let t_bot = (DETAIL_MIN - g0) / g1;
    if t_bot <= 0.0 || t_top > MAX_GROUND_RANGE {
        return None;
    }
    let f = |t: f64| {
        let (x, y) = (o.x + t * d.x, o.y + t * d.y);
        g0 + g1 * t - (w.height(x, y) - w.base(x, y))
    };
    let hxy = d.x.hypot(d.y);
    let (mut ta, mut fa) = {
        let t = (-g0 / g1).clamp(t_top, t_bot);
        (t, f(t))
    };
    let mut tb = (ta - fa / g1).clamp(t_top, t_bot);
    let mut fb = f(tb);
    for _ in 0..16 {
        if fb.abs() < 1e-7 || fb == fa {
            break;
        }
        let tn = (tb - fb * (tb - ta) / (fb - fa)).clamp(t_top, t_bot);
        (ta, fa) = (tb, fb);
        tb = tn;
        fb = f(tb);
    }
    if fb.abs() < 1e-5 {
        let (x, y) = (o.x + tb * d.x, o.y + tb * d.y);
        let reach = (tb - t_top) * hxy;
        // The curb distance is 1-Lipschitz: if the curb is further than the ray travelled
        // horizontally inside the bracket, no step lies in front of this hit.
        if w.curb_distance(x, y).0.abs() > reach + 0.05 {
            return Some(tb);
        }
    }
    let n = (((t_bot - t_top) * hxy / MARCH_STEP).ceil() as usize).clamp(2, MARCH_MAX_STEPS);
    let mut t0 = t_top;
    for i in 1..=n {
        let t1 = t_top + (t_bot - t_top) * i as f64 / n as f64;
        if f(t1) <= 0.0 {
            let (mut lo, mut hi) = (t0, t1);
            for _ in 0..40 {
                let mid = 0.5 * (lo + hi);
                if f(mid) > 0.0 {
                    lo = mid
                } else {
                    hi = mid
                }
            }
            return Some(0.5 * (lo + hi));
        }
        t0 = t1;
    }
    Some(t_bot)
}

/// Upward unit normal of the ground at (x, y).
pub(crate) fn ground_normal(w: &World, x: f64, y: f64) -> Vector3<f64> {
    let h = w.height(x, y);
    let hx = (w.height(x + NORMAL_EPS, y) - h) / NORMAL_EPS;
    let hy = (w.height(x, y + NORMAL_EPS) - h) / NORMAL_EPS;
    Vector3::new(-hx, -hy, 1.0).normalize()
}

/// Fraction of direct sunlight reaching `p` past the solids in `sets` (0 = full shadow).
pub(crate) fn sun_visibility(
    sets: &[&[Solid]],
    p: &Vector3<f64>,
    sun: &Vector3<f64>,
    dapple: &Field,
) -> f64 {
    let mut vis = 1.0;
    for set in sets {
        for s in set.iter() {
            if s.intersect(p, sun, 1e-4, 1e4).is_some() {
                if s.kind == Kind::Crown {
                    vis *= (CROWN_TRANSMIT * (1.0 + 1.5 * dapple.at(p.x, p.y))).clamp(0.0, 1.0);
                } else {
                    return 0.0;
                }
            }
        }
    }
    vis
}

/// Visible-band albedo of a solid at hit point `p` (windows, leaves, glass).
pub(crate) fn solid_albedo(s: &Solid, h: &Hit, p: &Vector3<f64>, leaves: &Field) -> f64 {
    let top = h.normal.z > 0.5;
    match s.kind {
        Kind::Building if !top => {
            // Facade with a window grid: 3 m floors, 2.5 m bays.
            let along = p.x * -h.normal.y + p.y * h.normal.x;
            let floor = (p.z / 3.0).fract();
            let bay = (along / 2.5).rem_euclid(1.0);
            if (0.35..0.8).contains(&floor) && (0.2..0.8).contains(&bay) {
                0.06
            } else {
                s.gray_side
            }
        }
        Kind::Crown => {
            s.gray_top * (0.55 + 0.9 * (0.5 + 0.5 * leaves.fbm(p.x + p.z, p.y - p.z, 3)))
        }
        _ if top => s.gray_top,
        _ => s.gray_side,
    }
}

/// Camera sensor and optics settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Sensor {
    /// Optical blur (Gaussian PSF σ), pixels.
    pub blur_px: f64,
    /// Vignetting: relative fall-off at the edge of the image circle.
    pub vignetting: f64,
    /// Full-well-equivalent: shot-noise variance of a signal s (0..1) is s / full_well.
    pub full_well: f64,
    /// Read noise σ (fraction of full scale).
    pub read_noise: f64,
    /// Display gamma applied before quantisation.
    pub gamma: f64,
}

/// Per-pixel result of the static scene: the part of every frame that does not move.
#[derive(Debug)]
pub(crate) struct StaticPass {
    width: usize,
    height: usize,
    /// Map-frame ray direction (NaN outside the image circle).
    dir: Vec<[f32; 3]>,
    /// Distance to the static hit (∞ = sky).
    t: Vec<f32>,
    /// Radiance from sky light (or the sky itself).
    amb: Vec<f32>,
    /// Radiance from direct sun, already shadowed by static solids.
    sun: Vec<f32>,
    /// Relative radius in the image circle (for vignetting), NaN outside.
    rad: Vec<f32>,
    /// Camera centre (map frame, local).
    center: Vector3<f64>,
}

/// Everything the fisheye sees of the scene.
#[derive(Debug, Clone, Copy)]
pub(crate) struct View<'a> {
    /// World.
    pub world: &'a World,
    /// Appearance fields.
    pub look: &'a Appearance,
    /// Static solids (buildings, trees, parked cars during the frames).
    pub(crate) statics: &'a [Solid],
    /// Lighting of the frames.
    pub light: Light,
}

fn sky_radiance(d: &Vector3<f64>, light: &Light) -> f64 {
    (light.ambient + 0.5 * light.sun_irr) * (1.1 + 0.6 * d.z.max(0.0))
}

/// Cast every pixel of `cam` at pose `pose` (map frame = the world's local frame) into the static
/// scene.
pub(crate) fn static_pass(v: &View, cam: &Camera, pose: &CamFromMap) -> StaticPass {
    let (w, h) = (cam.width() as usize, cam.height() as usize);
    let map_from_cam = pose.inverse();
    let center = pose.center().coords;
    let max_theta = cam.max_theta();
    let r_edge = edge_radius(cam);
    let (cxp, cyp) = principal_point(cam);
    let leaves = Field::new(v.world.seed ^ 0xC0, 0.4);
    let dapple = Field::new(v.world.seed ^ 0xC1, 0.5);
    let mut dir = vec![[f32::NAN; 3]; w * h];
    let mut t = vec![f32::INFINITY; w * h];
    let mut amb = vec![0f32; w * h];
    let mut sun = vec![0f32; w * h];
    let mut rad = vec![f32::NAN; w * h];
    dir.par_chunks_mut(w)
        .zip(t.par_chunks_mut(w))
        .zip(amb.par_chunks_mut(w))
        .zip(sun.par_chunks_mut(w))
        .zip(rad.par_chunks_mut(w))
        .enumerate()
        .for_each(|(row, ((((dr, tr), ar), sr), rr))| {
            for col in 0..w {
                let px = Point2::new(col as f64, row as f64);
                let Ok(b) = cam.unproject(&px) else { continue };
                if b.z.clamp(-1.0, 1.0).acos() > max_theta || !cam.in_image(&px) {
                    continue;
                }
                let d = map_from_cam.rotate(&b.into_inner());
                dr[col] = [d.x as f32, d.y as f32, d.z as f32];
                rr[col] = ((px.x - cxp).hypot(px.y - cyp) / r_edge) as f32;
                let tg = intersect_ground(v.world, &center, &d);
                let solid = nearest(v.statics, &center, &d, tg.unwrap_or(f64::INFINITY));
                let (albedo, n, p, tt) = match (solid, tg) {
                    (Some((i, hit)), _) => {
                        let p = center + hit.t * d;
                        (
                            solid_albedo(&v.statics[i], &hit, &p, &leaves),
                            hit.normal,
                            p,
                            hit.t,
                        )
                    }
                    (None, Some(tg)) => {
                        let p = center + tg * d;
                        let s = v.world.surface(p.x, p.y);
                        (
                            v.look.visible(v.world, &s, p.x, p.y),
                            ground_normal(v.world, p.x, p.y),
                            p,
                            tg,
                        )
                    }
                    (None, None) => {
                        ar[col] = sky_radiance(&d, &v.light) as f32;
                        continue;
                    }
                };
                tr[col] = tt as f32;
                ar[col] = (albedo * v.light.ambient * (0.5 + 0.5 * n.z)) as f32;
                let cos = n.dot(&v.light.sun);
                if cos > 0.0 && v.light.sun_irr > 0.0 {
                    let vis = sun_visibility(&[v.statics], &(p + n * 1e-3), &v.light.sun, &dapple);
                    sr[col] = (albedo * v.light.sun_irr * cos * vis) as f32;
                }
            }
        });
    StaticPass {
        width: w,
        height: h,
        dir,
        t,
        amb,
        sun,
        rad,
        center,
    }
}

/// Principal point of a camera.
pub(crate) fn principal_point(cam: &Camera) -> (f64, f64) {
    match cam {
        Camera::Mei(m) => (m.cx, m.cy),
        Camera::Equidistant(m) => (m.cx, m.cy),
    }
}

/// Pixel radius of the image circle's edge (along +x from the principal point).
pub(crate) fn edge_radius(cam: &Camera) -> f64 {
    let th = cam.max_theta();
    cam.project(&Vector3::new(th.sin(), 0.0, th.cos()))
        .map(|p| (p.x - principal_point(cam).0).abs())
        .unwrap_or(cam.width() as f64 * 0.5)
}

impl StaticPass {
    /// Exposure scale that puts the bright end of the static ground (98th percentile) at 0.85.
    pub(crate) fn auto_exposure(&self) -> f64 {
        let mut v: Vec<f32> = (0..self.t.len())
            .filter(|&i| self.t[i].is_finite())
            .map(|i| self.amb[i] + self.sun[i])
            .collect();
        if v.is_empty() {
            return 1.0;
        }
        let k = ((v.len() as f64 * 0.98) as usize).min(v.len() - 1);
        let (_, p98, _) = v.select_nth_unstable_by(k, f32::total_cmp);
        0.85 / (*p98 as f64).max(1e-6)
    }

    /// Render one frame with the moving `dynamic` solids: 8-bit gray, row-major.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn frame(
        &self,
        v: &View,
        dynamic: &[Solid],
        sensor: &Sensor,
        exposure: f64,
        noise_seed: u64,
    ) -> Vec<u8> {
        let (w, h) = (self.width, self.height);
        let leaves = Field::new(v.world.seed ^ 0xC0, 0.4);
        let dapple = Field::new(v.world.seed ^ 0xC1, 0.5);
        let c = self.center;
        let mut lin = vec![0f32; w * h];
        lin.par_chunks_mut(w).enumerate().for_each(|(row, out)| {
            for (col, o) in out.iter_mut().enumerate() {
                let i = row * w + col;
                let dd = self.dir[i];
                if dd[0].is_nan() {
                    continue;
                }
                let d = Vector3::new(dd[0] as f64, dd[1] as f64, dd[2] as f64).normalize();
                let ts = self.t[i] as f64;
                if let Some((k, hit)) = nearest(dynamic, &c, &d, ts) {
                    let p = c + hit.t * d;
                    let a = solid_albedo(&dynamic[k], &hit, &p, &leaves);
                    let n = hit.normal;
                    let mut l = a * v.light.ambient * (0.5 + 0.5 * n.z);
                    let cos = n.dot(&v.light.sun);
                    if cos > 0.0 && v.light.sun_irr > 0.0 {
                        let q = p + n * 1e-3;
                        l += a
                            * v.light.sun_irr
                            * cos
                            * sun_visibility(&[v.statics, dynamic], &q, &v.light.sun, &dapple);
                    }
                    *o = l as f32;
                } else if ts.is_finite() && self.sun[i] > 0.0 {
                    let p = c + ts * d;
                    let vis = sun_visibility(
                        &[dynamic],
                        &(p + Vector3::z() * 1e-3),
                        &v.light.sun,
                        &dapple,
                    );
                    *o = self.amb[i] + self.sun[i] * vis as f32;
                } else {
                    *o = self.amb[i] + self.sun[i];
                }
            }
        });
        gaussian_blur(&mut lin, w, h, sensor.blur_px);
        let mut img = vec![0u8; w * h];
        img.par_chunks_mut(w).enumerate().for_each(|(row, out)| {
            for (col, o) in out.iter_mut().enumerate() {
                let i = row * w + col;
                let r = self.rad[i];
                let vig = if r.is_nan() {
                    0.0
                } else {
                    1.0 - sensor.vignetting * (r as f64).powi(2)
                };
                let s = (lin[i] as f64 * exposure * vig).clamp(0.0, 1.0);
                let sigma = (s / sensor.full_well + sensor.read_noise * sensor.read_noise).sqrt();
                let noisy =
                    (s + sigma * gauss(hash3(noise_seed, col as i64, row as i64))).clamp(0.0, 1.0);
                *o = (noisy.powf(1.0 / sensor.gamma) * 255.0).round() as u8;
            }
        });
        img
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ground_hit_lies_on_the_height_field() {
        let w = World::generate(5);
        let o = Vector3::new(1.0, 2.0, w.height(1.0, 2.0) + 8.0);
        for i in 0..400 {
            let az = i as f64 * 0.7;
            let th = (i as f64 / 400.0) * 88f64.to_radians();
            let d = Vector3::new(th.sin() * az.cos(), th.sin() * az.sin(), -th.cos());
            let t = intersect_ground(&w, &o, &d).unwrap();
            let p = o + t * d;
            assert!(
                (p.z - w.height(p.x, p.y)).abs() < 1e-4,
                "θ={th} miss {}",
                p.z - w.height(p.x, p.y)
            );
            // Nothing earlier on the ray is below the ground (first hit).
            for k in 1..50 {
                let q = o + t * (k as f64 / 50.0) * d;
                assert!(q.z >= w.height(q.x, q.y) - 1e-4);
            }
        }
        // Upward rays see the sky.
        assert!(intersect_ground(&w, &o, &Vector3::new(0.0, 0.6, 0.8)).is_none());
    }

    #[test]
    fn blur_preserves_mean() {
        let (w, h) = (17, 13);
        let mut p: Vec<f32> = (0..w * h).map(|i| ((i * 7919) % 13) as f32).collect();
        let m0: f32 = p.iter().sum::<f32>() / p.len() as f32;
        gaussian_blur(&mut p, w, h, 1.5);
        let m1: f32 = p.iter().sum::<f32>() / p.len() as f32;
        assert!((m0 - m1).abs() < 0.3);
    }
}
