//! The `gantry` preset's extra sensors: a gantry over one approach of the intersection carrying
//! the fisheye, a perspective camera looking along the road 20–30° below the horizontal, and a
//! 64-ring LiDAR whose one sweep is the perspective camera's point set (docs/simulator.md,
//! "Gantry preset").
//!
//! The scene is built to be as hard as a real roadside gantry: the camera sees the road at
//! grazing angles, the LiDAR's rings draw sparse concentric arcs that never reach the road right
//! under the pole, and a low sun behind the camera throws the long shadows of the pole, the beam
//! and the signs across the markings the camera sees — which the LiDAR, an active sensor, does
//! not see at all.

use super::appearance::Appearance;
use super::noise::{gauss, hash3, mix64};
use super::render::intersect_ground;
use super::solids::{nearest, Kind, Shape, Solid};
use super::world::{World, CURB_W};
use crate::camera::{Camera, Mei};
use crate::pose::CamFromMap;
use nalgebra::{Matrix3, Point3, Rotation3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::{PI, TAU};

/// LiDAR rings (an Ouster OS1-64).
pub(crate) const RINGS: usize = 64;
/// Columns of one sweep (the OS1's 1024 × 10 Hz mode).
pub(crate) const COLUMNS: usize = 1024;
/// Elevation of the top ring in the LiDAR's level frame, degrees. With [`RING_BOTTOM_DEG`], the
/// rings' spread as the real S110 gantry scan has it (ring 0 at −0.4°, ring 63 at −21.5°): the
/// mount aims the whole fan below the horizon.
pub(crate) const RING_TOP_DEG: f64 = -0.4;
/// Elevation of the bottom ring, degrees.
pub(crate) const RING_BOTTOM_DEG: f64 = -21.5;
/// Returns closer than this are dropped (the sensor's blind zone; it also hides the pole the
/// LiDAR is clamped to), metres.
const MIN_RANGE_M: f64 = 0.8;
/// No return beyond this, metres.
const MAX_RANGE_M: f64 = 120.0;
/// Range at which a return of reflectivity 0 is still detected; a brighter target reaches
/// further, up to [`MAX_RANGE_M`] at 255 (the detection range grows as √reflectivity).
const DARK_RANGE_M: f64 = 35.0;
/// Range noise σ, metres.
const RANGE_SIGMA_M: f64 = 0.02;
/// Multiplicative reflectivity noise σ of one return.
const REFL_MUL: f64 = 0.15;
/// Additive reflectivity noise σ of one return (0–255 scale).
const REFL_ADD: f64 = 3.0;
/// Perspective image size, pixels.
const PERSP_SIZE: (u32, u32) = (1280, 800);
/// Perspective focal length before the per-unit jitter, pixels (a 70° × 47° field of view).
const PERSP_F: f64 = 914.0;

/// One LiDAR return, in the LiDAR's frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SweepPoint {
    /// Position in the LiDAR frame (x forward, y left, z up), metres.
    pub xyz: [f32; 3],
    /// Calibrated reflectivity, 0–255.
    pub reflectivity: u16,
    /// Ring, 0 (top) … 63 (bottom).
    pub ring: u8,
    /// Measured range, millimetres.
    pub range_mm: u32,
}

/// The gantry and its sensors, in the world's local frame.
#[derive(Debug, Clone)]
pub struct Rig {
    /// Pole, beam, hanging signs and roadside sign posts (they cast the shadows).
    pub solids: Vec<Solid>,
    /// Perspective camera (Mei with ξ = 0, no distortion: a plain pinhole).
    pub camera: Camera,
    /// Its true pose in the world's local frame.
    pub pose_local: CamFromMap,
    /// LiDAR-to-world rotation (local frame).
    pub lidar_rotation: Rotation3<f64>,
    /// LiDAR origin in the local frame.
    pub lidar_origin: Vector3<f64>,
    /// The camera's view direction, radians from +x (east).
    pub view_angle: f64,
    /// Camera pitch below the horizontal, degrees.
    pub pitch_down_deg: f64,
    /// Sun azimuth (clockwise from north) and elevation, degrees: low, behind the camera.
    pub sun_az_el_deg: [f64; 2],
}

impl Rig {
    /// The perspective camera's pose in the LiDAR frame: what `refine --points` compares a sweep
    /// with.
    pub fn pose_in_lidar(&self) -> CamFromMap {
        let r = self.pose_local.rotation * self.lidar_rotation;
        let c_world = self.pose_local.center().coords;
        let c = self.lidar_rotation.inverse() * (c_world - self.lidar_origin);
        CamFromMap::from_center(r, &Point3::from(c))
    }

    /// A world point (local frame) in the LiDAR frame.
    pub fn to_lidar(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.lidar_rotation.inverse() * (p - self.lidar_origin)
    }
}

/// A rotation whose columns are the camera axes in the world: looking along `view` (radians from
/// +x) `pitch` below the horizontal, rolled by `roll` about the optical axis.
fn look_rotation(view: f64, pitch: f64, roll: f64) -> Rotation3<f64> {
    let (sv, cv) = view.sin_cos();
    let (sp, cp) = pitch.sin_cos();
    let z = Vector3::new(cp * cv, cp * sv, -sp);
    let x0 = Vector3::new(sv, -cv, 0.0);
    let y0 = z.cross(&x0);
    let (sr, cr) = roll.sin_cos();
    let x = x0 * cr + y0 * sr;
    let y = z.cross(&x);
    Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]))
}

/// A gray-ish solid of `kind`.
fn solid(shape: Shape, kind: Kind, gray: (f64, f64), tex: u64) -> Solid {
    let rgb = |g: f64| [g, g, g * 1.02];
    Solid::new(shape, kind, gray, (rgb(gray.0), rgb(gray.1)), tex)
}

/// Build the gantry over the fisheye at `fisheye` (local frame), facing one approach; `seed`
/// drives every draw here, so the other presets' scenes do not change.
pub(crate) fn rig(world: &World, fisheye: &CamFromMap, seed: u64) -> Rig {
    let mut rng = ChaCha8Rng::seed_from_u64(mix64(seed ^ 0x6A27_7259));
    let c = fisheye.center().coords;
    let k = rng.random_range(0..world.approaches.len());
    let a = &world.approaches[k];
    let view = a.angle + rng.random_range(-10f64..10.0).to_radians();
    let (sv, cv) = view.sin_cos();
    let fwd = Vector3::new(cv, sv, 0.0);
    // The beam runs across the road; the pole stands on the side drawn here.
    let side = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    let across = Vector3::new(sv, -cv, 0.0) * side;
    let pole = c + across * 1.0;
    let top = c.z + 0.75;
    let mut solids = vec![solid(
        Shape::Cylinder {
            cx: pole.x,
            cy: pole.y,
            r: 0.16,
            z0: world.height(pole.x, pole.y) - 0.1,
            z1: top,
        },
        Kind::Trunk,
        (0.5, 0.45),
        rng.random(),
    )];
    let span = rng.random_range(10.0..16.0);
    let beam_c = pole - across * (span / 2.0 - 0.3);
    let beam_yaw = across.y.atan2(across.x);
    solids.push(solid(
        Shape::Box {
            cx: beam_c.x,
            cy: beam_c.y,
            z0: c.z + 0.35,
            z1: top,
            hl: span / 2.0,
            hw: 0.2,
            yaw: beam_yaw,
        },
        Kind::Trunk,
        (0.5, 0.45),
        rng.random(),
    ));
    // Signs hang from the beam over the lanes, clear of the fisheye's near field.
    let signs = rng.random_range(1..=2);
    for i in 0..signs {
        let along = 3.5 + i as f64 * 4.0 + rng.random_range(0.0..1.5);
        let p = pole - across * along;
        let hl = rng.random_range(0.9..1.5);
        solids.push(solid(
            Shape::Box {
                cx: p.x,
                cy: p.y,
                z0: c.z - rng.random_range(0.9..1.4),
                z1: c.z + 0.35,
                hl,
                hw: 0.04,
                yaw: beam_yaw,
            },
            Kind::Sign,
            (0.35, 0.3),
            rng.random(),
        ));
    }
    // Sign posts at the curbs ahead: short poles with a plate, their shadows cross the lanes.
    for l_side in [1.0, -1.0] {
        let s = rng.random_range(10.0..24.0);
        let w = if l_side > 0.0 { a.w_in } else { a.w_out };
        let (x, y) = a.point(s, l_side * (w + CURB_W + 0.4));
        let z = world.height(x, y);
        let h = rng.random_range(2.4..3.2);
        solids.push(solid(
            Shape::Cylinder {
                cx: x,
                cy: y,
                r: 0.04,
                z0: z,
                z1: z + h,
            },
            Kind::Trunk,
            (0.45, 0.4),
            rng.random(),
        ));
        solids.push(solid(
            Shape::Box {
                cx: x,
                cy: y,
                z0: z + h - 0.05,
                z1: z + h + 0.75,
                hl: 0.4,
                hw: 0.02,
                yaw: a.angle + PI / 2.0,
            },
            Kind::Sign,
            (0.4, 0.35),
            rng.random(),
        ));
    }
    let f = PERSP_F * rng.random_range(0.98..1.02);
    let (w, h) = PERSP_SIZE;
    let diag = ((w as f64 / 2.0).hypot(h as f64 / 2.0) / f)
        .atan()
        .to_degrees();
    let camera = Camera::Mei(Mei {
        width: w,
        height: h,
        fx: f,
        fy: f,
        cx: (w as f64 - 1.0) / 2.0 + rng.random_range(-4.0..4.0),
        cy: (h as f64 - 1.0) / 2.0 + rng.random_range(-4.0..4.0),
        skew: 0.0,
        xi: 0.0,
        k1: 0.0,
        k2: 0.0,
        p1: 0.0,
        p2: 0.0,
        // The image's corners lie at `diag` off the axis; the margin keeps them inside.
        fov_deg: Some(2.0 * diag + 4.0),
    });
    let pitch_down = rng.random_range(20.0..30.0);
    let centre = c - across * 0.35 + Vector3::new(0.0, 0.0, rng.random_range(-0.1..0.1));
    let r_world_from_cam = look_rotation(
        view,
        f64::to_radians(pitch_down),
        rng.random_range(-1f64..1.0).to_radians(),
    );
    let pose_local = CamFromMap::from_center(r_world_from_cam.inverse(), &Point3::from(centre));
    // The LiDAR: clamped to the pole's road side, below the camera, its x axis anywhere, its
    // mount level to half a degree.
    let lidar_origin = pole + fwd * 0.35 - Vector3::new(0.0, 0.0, rng.random_range(0.3..0.7));
    let lidar_rotation = Rotation3::from_euler_angles(
        rng.random_range(-0.5f64..0.5).to_radians(),
        rng.random_range(-0.5f64..0.5).to_radians(),
        rng.random_range(-PI..PI),
    );
    // The sun low and behind the camera, within 35° of straight behind it.
    let back = view + PI + rng.random_range(-35f64..35.0).to_radians();
    let az = back.cos().atan2(back.sin()).to_degrees().rem_euclid(360.0);
    let el = rng.random_range(8.0..25.0);
    Rig {
        solids,
        camera,
        pose_local,
        lidar_rotation,
        lidar_origin,
        view_angle: view.rem_euclid(TAU),
        pitch_down_deg: pitch_down,
        sun_az_el_deg: [az, el],
    }
}

/// LiDAR reflectivity (0–255, before noise) of a solid: retroreflective sign sheeting is the
/// brightest thing in a scan; glass returns little.
fn solid_reflectivity(kind: Kind, tex: u64) -> f64 {
    let jitter = (tex % 1000) as f64 / 1000.0;
    match kind {
        Kind::Sign => 220.0 + 30.0 * jitter,
        Kind::Building => 30.0 + 30.0 * jitter,
        Kind::Trunk => 25.0 + 20.0 * jitter,
        Kind::Crown => 20.0 + 25.0 * jitter,
        Kind::VehicleBody => 15.0 + 50.0 * jitter,
        Kind::VehicleCabin => 8.0 + 6.0 * jitter,
        Kind::Pedestrian => 20.0 + 20.0 * jitter,
    }
}

/// One sweep of the gantry's LiDAR over `world` with the solids in `sets` (statics, parked and
/// moving road users): every ring and column cast as a ray, the first surface it meets returned
/// if it lies within the detection range for its reflectivity. Ground reflectivity comes from the
/// same material model as the map's LiDAR layer; shadows play no part (the sensor is active).
pub(crate) fn sweep(
    world: &World,
    look: &Appearance,
    rig: &Rig,
    sets: &[&[Solid]],
    noise_seed: u64,
) -> Vec<SweepPoint> {
    let o = rig.lidar_origin;
    let mut out = Vec::new();
    for ring in 0..RINGS {
        let el = (RING_TOP_DEG
            + (RING_BOTTOM_DEG - RING_TOP_DEG) * ring as f64 / (RINGS - 1) as f64)
            .to_radians();
        for col in 0..COLUMNS {
            let az = TAU * col as f64 / COLUMNS as f64;
            let dl = Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
            let d = rig.lidar_rotation * dl;
            let tg = intersect_ground(world, &o, &d).filter(|t| *t < MAX_RANGE_M);
            let mut best: Option<(f64, f64, Vector3<f64>)> = tg.map(|t| {
                let p = o + t * d;
                let s = world.surface(p.x, p.y);
                let n = super::render::ground_normal(world, p.x, p.y);
                (t, look.lidar(&s, p.x, p.y), n)
            });
            for set in sets {
                let limit = best.map_or(MAX_RANGE_M, |b| b.0);
                if let Some((i, hit)) = nearest(set, &o, &d, limit) {
                    best = Some((
                        hit.t,
                        solid_reflectivity(set[i].kind, set[i].tex),
                        hit.normal,
                    ));
                }
            }
            let Some((t, r0, n)) = best else { continue };
            if t < MIN_RANGE_M {
                continue;
            }
            let h = hash3(noise_seed, ring as i64, col as i64);
            // Returns weaken away from normal incidence; the calibrated channel keeps a trace.
            let cos_inc = n.dot(&-d).clamp(0.0, 1.0);
            let r = r0 * (0.6 + 0.4 * cos_inc) * (1.0 + REFL_MUL * gauss(h))
                + REFL_ADD * gauss(h ^ 0x51);
            let r = r.round().clamp(1.0, 255.0);
            if t > DARK_RANGE_M + (MAX_RANGE_M - DARK_RANGE_M) * (r / 255.0).sqrt() {
                continue;
            }
            let tm = t + RANGE_SIGMA_M * gauss(h ^ 0xA7);
            let p = dl * tm;
            out.push(SweepPoint {
                xyz: [p.x as f32, p.y as f32, p.z as f32],
                reflectivity: r as u16,
                ring: ring as u8,
                range_mm: (tm * 1000.0).round() as u32,
            });
        }
    }
    out
}

/// The sweep as an ASCII PCD with the Ouster's field names (`x y z reflectivity ring range`):
/// `refine --points` reads its `reflectivity`.
pub fn to_pcd(points: &[SweepPoint]) -> String {
    let mut s = format!(
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z reflectivity ring range\nSIZE 4 4 4 2 1 4\nTYPE F F F U U U\nCOUNT 1 1 1 1 1 1\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA ascii\n",
        n = points.len()
    );
    for p in points {
        s.push_str(&format!(
            "{:.4} {:.4} {:.4} {} {} {}\n",
            p.xyz[0], p.xyz[1], p.xyz[2], p.reflectivity, p.ring, p.range_mm
        ));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn look_rotation_points_down_the_road() {
        let r = look_rotation(0.3, 25f64.to_radians(), 0.0);
        let z = r * Vector3::z();
        assert!((z.z + 25f64.to_radians().sin()).abs() < 1e-12);
        assert!((z.y.atan2(z.x) - 0.3).abs() < 1e-12);
        // Image down (+y) points down in the world; a proper rotation.
        assert!((r * Vector3::y()).z < 0.0);
        assert!((r.matrix().determinant() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn sweep_never_returns_under_the_pole_and_keeps_ring_order() {
        let w = World::generate(11);
        let look = Appearance::new(w.seed);
        let fisheye = CamFromMap::from_center_ypr(
            &Point3::new(0.0, 0.0, w.height(0.0, 0.0) + 7.5),
            0.0,
            0.0,
            0.0,
        );
        let rig = rig(&w, &fisheye, 3);
        let pts = sweep(&w, &look, &rig, &[&w.statics, &rig.solids], 9);
        assert!(pts.len() > 20_000, "{} returns", pts.len());
        let below = rig.lidar_origin.z - w.height(rig.lidar_origin.x, rig.lidar_origin.y);
        // The bottom ring meets level ground at height / tan(21.5°); within half that radius
        // every ray is still half the height up, so nothing near the road can return there.
        let nearest_ground = below / RING_BOTTOM_DEG.to_radians().tan().abs();
        let close = pts
            .iter()
            .filter(|p| (p.xyz[0] as f64).hypot(p.xyz[1] as f64) < 0.5 * nearest_ground)
            .filter(|p| (p.xyz[2] as f64) < -(below - 1.0))
            .count();
        assert_eq!(close, 0, "ground returns under the pole");
        let rings: std::collections::BTreeSet<u8> = pts.iter().map(|p| p.ring).collect();
        assert_eq!(rings.len(), RINGS);
    }
}
