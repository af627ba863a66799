//! The simulated world: a seeded road intersection as pure functions of map position.
//!
//! Everything a sensor sees of the ground is [`World::surface`] (material, paint wear, height) or
//! [`World::height`] evaluated at a map point, and everything above the ground is a [`Solid`]. The
//! LiDAR layers, the satellite image and every fisheye ray query the same functions, so the scene
//! is one world seen through different sensors — only the per-sensor appearance differs (see
//! [`super::appearance`]).
//!
//! Coordinates here are *local*: metres east/north of the intersection centre (the scene adds
//! the UTM origin when writing files), z absolute height in metres.
//!
//! Geometry: `k` approaches leave the centre at angles `φ_i`. In approach i's frame a point has
//! `s` (along `u_i`, outward) and `l` (along the left normal `n_i`); inbound lanes (towards the
//! centre, right-hand traffic) occupy `0 < l < w_in`, outbound lanes `−w_out < l < 0`. Between
//! neighbouring approaches lies a corner block whose curb line is the rounded intersection of the
//! two road edges (curb-return radius r). `D` = signed distance from the curb (negative on the
//! road) drives road crown, curb step, lawn and sidewalk.

use super::noise::{smoothstep, Field};
use super::solids::{Kind, Shape, Solid};
use rand::{Rng, RngCore, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::{PI, TAU};

/// Lane width range, metres (US arterials 3.0–3.7 m).
const LANE_W: (f64, f64) = (3.2, 3.7);
/// Paved shoulder/gutter between the edge line and the curb, metres.
const SHOULDER: f64 = 0.6;
/// Width of longitudinal lines (US 4–6 in), metres.
const LINE_W: f64 = 0.13;
/// Centre of each yellow line of a double centre line, from the centreline, metres.
const DOUBLE_YELLOW_OFFSET: f64 = 0.15;
/// Dashed lane line: 3 m line, 9 m gap (US 10 ft / 30 ft).
const DASH_ON: f64 = 3.0;
/// Dash period.
const DASH_PERIOD: f64 = 12.0;
/// Stop bar depth (US 12–24 in), metres.
const STOP_BAR_W: f64 = 0.45;
/// Crosswalk depth along the road, metres.
const CROSSWALK_DEPTH: f64 = 3.0;
/// Continental crosswalk bar width and gap, metres.
const ZEBRA_BAR: f64 = 0.6;
/// Gap between the crosswalk and the stop bar, metres.
const STOP_BAR_SETBACK: f64 = 1.2;
/// Lane lines before the stop bar are solid for this long, metres.
const SOLID_LANE_RUN: f64 = 20.0;
/// Curb top width, metres.
pub(crate) const CURB_W: f64 = 0.15;
/// Horizontal run of the curb face (a steep ramp, so normals stay finite), metres.
pub(crate) const CURB_RAMP: f64 = 0.02;
/// Distance from the curb over which the road rises to its crown, metres.
const CROWN_RUN: f64 = 3.5;
/// Cross slope of sidewalks and lawns away from the road (2 %).
const SIDE_SLOPE: f64 = 0.015;
/// Sidewalk/lawn rise stops after this distance from the curb, metres.
const SIDE_SLOPE_RUN: f64 = 8.0;
/// Ground detail bounds relative to the sloped base plane (see [`World::height`]), metres. The ray
/// caster relies on these to bracket the ground.
pub(crate) const DETAIL_MIN: f64 = -0.05;
/// Upper detail bound.
pub(crate) const DETAIL_MAX: f64 = 0.45;

/// Ground material.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Material {
    /// Weathered asphalt.
    Asphalt,
    /// Newer asphalt patch (visibly darker, about the same to the LiDAR).
    Patch,
    /// Sealed crack (tar).
    Crack,
    /// White paint.
    PaintWhite,
    /// Yellow paint.
    PaintYellow,
    /// Cast-iron manhole cover.
    Manhole,
    /// Storm-drain grate.
    Drain,
    /// Concrete curb.
    Curb,
    /// Concrete sidewalk.
    Sidewalk,
    /// Grass.
    Grass,
}

/// What a point of the ground is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Surface {
    /// Material.
    pub mat: Material,
    /// Paint wear 0 (fresh) … 1 (gone); for other materials a per-feature age in 0..1.
    pub wear: f64,
    /// Signed distance from the curb (negative on the road), metres.
    pub d_curb: f64,
}

/// Paint colour of a marking.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Paint {
    /// White.
    White,
    /// Yellow.
    Yellow,
}

/// A painted convex polygon in an approach's (s, l) frame (stop bar, zebra bar, arrow part).
#[derive(Debug, Clone, PartialEq)]
pub struct Mark {
    /// Identifier prefix of its control points.
    pub id: String,
    /// Colour.
    pub paint: Paint,
    /// Wear 0..1.
    pub wear: f64,
    /// Counter-clockwise vertices (s, l).
    pub poly: Vec<[f64; 2]>,
    /// Whether the vertices are control points (arrow parts share vertices; only outer ones are).
    pub control: Vec<bool>,
    bbox: [f64; 4],
}

impl Mark {
    fn new(id: String, paint: Paint, wear: f64, poly: Vec<[f64; 2]>, control: Vec<bool>) -> Self {
        let mut bbox = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        for p in &poly {
            bbox[0] = bbox[0].min(p[0]);
            bbox[1] = bbox[1].min(p[1]);
            bbox[2] = bbox[2].max(p[0]);
            bbox[3] = bbox[3].max(p[1]);
        }
        Mark {
            id,
            paint,
            wear,
            poly,
            control,
            bbox,
        }
    }

    #[inline]
    fn contains(&self, s: f64, l: f64) -> bool {
        if s < self.bbox[0] || l < self.bbox[1] || s > self.bbox[2] || l > self.bbox[3] {
            return false;
        }
        let n = self.poly.len();
        (0..n).all(|i| {
            let a = self.poly[i];
            let b = self.poly[(i + 1) % n];
            (b[0] - a[0]) * (l - a[1]) - (b[1] - a[1]) * (s - a[0]) >= 0.0
        })
    }
}

/// One road leaving the intersection.
#[derive(Debug, Clone)]
pub struct Approach {
    /// Direction angle from +x (east), radians, in [0, 2π).
    pub angle: f64,
    /// Unit direction (outward).
    pub u: [f64; 2],
    /// Unit left normal.
    pub n: [f64; 2],
    /// Lane width.
    pub lane_w: f64,
    /// Inbound lanes (towards the centre).
    pub lanes_in: u32,
    /// Outbound lanes.
    pub lanes_out: u32,
    /// Curb offset on the inbound (+l) side.
    pub w_in: f64,
    /// Curb offset on the outbound (−l) side.
    pub w_out: f64,
    /// Start of the crosswalk (or of the markings if there is none), along s.
    pub s_cw: f64,
    /// Whether there is a painted crosswalk.
    pub crosswalk: bool,
    /// Near edge of the stop bar.
    pub s_stop: f64,
    /// Double yellow centre line (else dashed single).
    pub double_yellow: bool,
    /// Wear of this approach's longitudinal lines.
    pub line_wear: f64,
    /// Painted polygons (stop bar, crosswalk bars, arrows).
    pub marks: Vec<Mark>,
}

impl Approach {
    /// (s, l) of a local point.
    #[inline]
    pub(crate) fn local(&self, x: f64, y: f64) -> (f64, f64) {
        (x * self.u[0] + y * self.u[1], x * self.n[0] + y * self.n[1])
    }

    /// Local point of (s, l).
    #[inline]
    pub(crate) fn point(&self, s: f64, l: f64) -> (f64, f64) {
        (s * self.u[0] + l * self.n[0], s * self.u[1] + l * self.n[1])
    }

    /// Paint at (s, l): colour and wear, if any.
    fn paint(&self, s: f64, l: f64) -> Option<(Paint, f64)> {
        if s < self.s_cw - 0.5 || l > self.w_in || l < -self.w_out {
            return None;
        }
        for m in &self.marks {
            if m.contains(s, l) {
                return Some((m.paint, m.wear));
            }
        }
        let half = 0.5 * LINE_W;
        let lines_from = self.s_cw + CROSSWALK_DEPTH + 0.3;
        if s < lines_from {
            return None;
        }
        // Centre line.
        if self.double_yellow {
            if (l.abs() - DOUBLE_YELLOW_OFFSET).abs() < half {
                return Some((Paint::Yellow, self.line_wear));
            }
        } else if l.abs() < half && (s - lines_from).rem_euclid(DASH_PERIOD) < DASH_ON {
            return Some((Paint::Yellow, self.line_wear));
        }
        let after_bar = self.s_stop + STOP_BAR_W;
        // Lane lines (between same-direction lanes) and edge lines.
        for (lanes, sign) in [(self.lanes_in, 1.0), (self.lanes_out, -1.0)] {
            let ll = l * sign;
            for k in 1..lanes {
                if (ll - k as f64 * self.lane_w).abs() < half {
                    let solid = sign > 0.0 && s < after_bar + SOLID_LANE_RUN;
                    let start = if sign > 0.0 { after_bar } else { lines_from };
                    if s >= start && (solid || (s - start).rem_euclid(DASH_PERIOD) < DASH_ON) {
                        return Some((Paint::White, self.line_wear));
                    }
                }
            }
            let edge = lanes as f64 * self.lane_w + 0.5 * LINE_W + 0.05;
            if (ll - edge).abs() < half {
                return Some((Paint::White, (self.line_wear + 0.15).min(0.9)));
            }
        }
        None
    }
}

/// The block between approach i and i+1 (counter-clockwise).
#[derive(Debug, Clone, Copy)]
pub struct Corner {
    /// Angular gap to the next approach, radians.
    pub gap: f64,
    /// Curb-return radius.
    pub radius: f64,
    /// Grass strip between curb and sidewalk.
    pub lawn_w: f64,
    /// Sidewalk width.
    pub sidewalk_w: f64,
}

/// A parked car's footprint on the ground (local frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Footprint {
    /// Centre x.
    pub x: f64,
    /// Centre y.
    pub y: f64,
    /// Heading.
    pub yaw: f64,
    /// Half length.
    pub hl: f64,
    /// Half width.
    pub hw: f64,
}

impl Footprint {
    /// Whether (x, y) lies within the footprint grown by `margin` (and by `extra` on the side
    /// away from `away_from`, the LiDAR's viewpoint: its occlusion shadow).
    pub(crate) fn contains(&self, x: f64, y: f64, margin: f64) -> bool {
        let (s, c) = self.yaw.sin_cos();
        let (dx, dy) = (x - self.x, y - self.y);
        let a = c * dx + s * dy;
        let b = -s * dx + c * dy;
        a.abs() <= self.hl + margin && b.abs() <= self.hw + margin
    }
}

#[derive(Debug, Clone, Copy)]
struct Disc {
    x: f64,
    y: f64,
    r: f64,
    age: f64,
}

#[derive(Debug, Clone, Copy)]
struct Rect {
    fp: Footprint,
    age: f64,
}

/// The seeded intersection.
#[derive(Debug, Clone)]
pub struct World {
    /// Master seed of the world's noise fields.
    pub seed: u64,
    /// Approaches sorted by angle.
    pub approaches: Vec<Approach>,
    /// Corner blocks: `corners[i]` lies between approach i and i+1.
    pub corners: Vec<Corner>,
    /// Height of the base plane at the centre, metres.
    pub z0: f64,
    /// Base-plane gradient (dz/dx, dz/dy).
    pub grad: [f64; 2],
    /// Road crown height above the gutter, metres.
    pub crown: f64,
    /// Curb height, metres (10–20 cm).
    pub curb_h: f64,
    manholes: Vec<Disc>,
    patches: Vec<Rect>,
    drains: Vec<Rect>,
    /// Buildings, trees and poles.
    pub statics: Vec<Solid>,
    /// Cars parked during the LiDAR mapping drive (holes in the LiDAR layers).
    pub lidar_parked: Vec<Footprint>,
    /// Cars parked when the satellite image was taken.
    pub satellite_parked: Vec<Solid>,
    /// Cars parked while the fisheye frames were taken (static across frames).
    pub camera_parked: Vec<Solid>,
    f_rough: Field,
    f_bump: Field,
    f_crack: Field,
    f_crack_mask: Field,
    f_wear: Field,
}

/// Pick `k` approach angles, at least `min_sep` apart, roughly evenly spread.
fn approach_angles(rng: &mut ChaCha8Rng, k: usize) -> Vec<f64> {
    let min_sep = 50f64.to_radians();
    loop {
        let base = rng.random_range(0.0..TAU);
        let mut a: Vec<f64> = (0..k)
            .map(|i| {
                let even = base + TAU * i as f64 / k as f64;
                let jitter = rng.random_range(-22f64..22.0).to_radians();
                (even + jitter).rem_euclid(TAU)
            })
            .collect();
        a.sort_by(f64::total_cmp);
        let ok = (0..k).all(|i| {
            let next = if i + 1 < k { a[i + 1] } else { a[0] + TAU };
            next - a[i] >= min_sep
        });
        // Two-approach "junctions" are bends, not straight roads.
        let bend_ok = k != 2 || ((a[1] - a[0]) - PI).abs() > 20f64.to_radians();
        if ok && bend_ok {
            return a;
        }
    }
}

/// Car body colours: (visible gray albedo, satellite RGB).
const CAR_COLOURS: [(f64, [f64; 3]); 8] = [
    (0.70, [0.78, 0.78, 0.80]), // white
    (0.45, [0.55, 0.56, 0.58]), // silver
    (0.08, [0.06, 0.06, 0.07]), // black
    (0.20, [0.22, 0.22, 0.24]), // dark gray
    (0.18, [0.45, 0.08, 0.07]), // red
    (0.12, [0.08, 0.14, 0.35]), // blue
    (0.30, [0.60, 0.55, 0.42]), // beige
    (0.22, [0.12, 0.30, 0.16]), // green
];

/// Solids of a car (body + cabin) or a box truck at (x, y, ground z) heading `yaw`.
pub(crate) fn vehicle(rng: &mut impl RngCore, x: f64, y: f64, z: f64, yaw: f64) -> Vec<Solid> {
    let (gray, rgb) = CAR_COLOURS[rng.random_range(0..CAR_COLOURS.len())];
    let tex = rng.next_u64();
    if rng.random_bool(0.12) {
        // Box truck / bus.
        let hl = rng.random_range(3.5..6.0);
        let top = z + rng.random_range(2.6..3.3);
        let body = Solid::new(
            Shape::Box {
                cx: x,
                cy: y,
                z0: z + 0.4,
                z1: top,
                hl,
                hw: 1.25,
                yaw,
            },
            Kind::VehicleBody,
            (gray.max(0.5), gray.max(0.5) * 0.8),
            ([0.8, 0.8, 0.8], rgb),
            tex,
        );
        return vec![body];
    }
    let hl = rng.random_range(2.1..2.6);
    let hw = rng.random_range(0.88..0.98);
    let body_top = z + rng.random_range(0.95..1.15);
    let body = Solid::new(
        Shape::Box {
            cx: x,
            cy: y,
            z0: z + 0.3,
            z1: body_top,
            hl,
            hw,
            yaw,
        },
        Kind::VehicleBody,
        (gray, gray * 0.85),
        (rgb, rgb),
        tex,
    );
    let back = rng.random_range(0.1..0.4);
    let (s, c) = yaw.sin_cos();
    let cabin = Solid::new(
        Shape::Box {
            cx: x - back * c,
            cy: y - back * s,
            z0: body_top - 0.01,
            z1: body_top + rng.random_range(0.42..0.55),
            hl: hl * 0.55,
            hw: hw * 0.92,
            yaw,
        },
        Kind::VehicleCabin,
        (gray, 0.05),
        (rgb, [0.04, 0.05, 0.06]),
        tex ^ 1,
    );
    vec![body, cabin]
}

/// A pedestrian (cylinder) at (x, y, ground z).
pub(crate) fn pedestrian(rng: &mut impl RngCore, x: f64, y: f64, z: f64) -> Solid {
    let g = rng.random_range(0.05..0.5);
    Solid::new(
        Shape::Cylinder {
            cx: x,
            cy: y,
            r: rng.random_range(0.2..0.27),
            z0: z,
            z1: z + rng.random_range(1.55..1.9),
        },
        Kind::Pedestrian,
        (0.12, g),
        ([0.15, 0.12, 0.1], [g, g, g]),
        rng.next_u64(),
    )
}

impl World {
    /// Generate the world for a seed.
    pub(crate) fn generate(seed: u64) -> World {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let k = match rng.random_range(0..10) {
            0 => 2,
            1..=3 => 3,
            _ => 4,
        };
        let angles = approach_angles(&mut rng, k);
        let mut approaches: Vec<Approach> = angles
            .iter()
            .map(|&a| {
                let major = rng.random_bool(0.6);
                let lanes_in = if major { rng.random_range(1..=2) } else { 1 };
                let lanes_out = if major { rng.random_range(1..=2) } else { 1 };
                let lane_w = rng.random_range(LANE_W.0..LANE_W.1);
                let (s, c) = a.sin_cos();
                Approach {
                    angle: a,
                    u: [c, s],
                    n: [-s, c],
                    lane_w,
                    lanes_in,
                    lanes_out,
                    w_in: lanes_in as f64 * lane_w + SHOULDER,
                    w_out: lanes_out as f64 * lane_w + SHOULDER,
                    s_cw: 0.0,
                    crosswalk: rng.random_bool(0.8),
                    s_stop: 0.0,
                    double_yellow: major || rng.random_bool(0.5),
                    line_wear: rng.random_range(0.0..0.6),
                    marks: Vec::new(),
                }
            })
            .collect();
        let corners: Vec<Corner> = (0..k)
            .map(|i| {
                let next = if i + 1 < k {
                    angles[i + 1]
                } else {
                    angles[0] + TAU
                };
                Corner {
                    gap: next - angles[i],
                    radius: rng.random_range(4.0..9.0),
                    lawn_w: if rng.random_bool(0.6) {
                        rng.random_range(1.0..2.5)
                    } else {
                        0.0
                    },
                    sidewalk_w: rng.random_range(1.5..3.0),
                }
            })
            .collect();
        // Where each approach's curb returns end: the crosswalk and stop bar go just beyond.
        for i in 0..k {
            let prev = (i + k - 1) % k;
            let mut s_tan: f64 = 2.0;
            // Corner i: approach i's left (+l, w_in) side against approach i+1's right side.
            let ci = corners[i];
            if ci.gap < PI - 1e-3 {
                let j = (i + 1) % k;
                let a = (approaches[j].w_out + approaches[i].w_in * ci.gap.cos()) / ci.gap.sin();
                s_tan = s_tan.max(a + ci.radius / (0.5 * ci.gap).tan());
            }
            // Corner prev: approach prev's left against approach i's right (−l, w_out) side.
            let cp = corners[prev];
            if cp.gap < PI - 1e-3 {
                let a = (approaches[prev].w_in + approaches[i].w_out * cp.gap.cos()) / cp.gap.sin();
                s_tan = s_tan.max(a + cp.radius / (0.5 * cp.gap).tan());
            }
            let ap = &mut approaches[i];
            ap.s_cw = s_tan - 1.0;
            ap.s_stop = ap.s_cw + CROSSWALK_DEPTH + STOP_BAR_SETBACK;
            build_marks(ap, i, &mut rng);
        }

        let mut w = World {
            seed,
            approaches,
            corners,
            z0: rng.random_range(240.0..290.0),
            grad: {
                let g = rng.random_range(0.003..0.02);
                let a = rng.random_range(0.0..TAU);
                [g * a.cos(), g * a.sin()]
            },
            crown: rng.random_range(0.06..0.13),
            curb_h: rng.random_range(0.10..0.20),
            manholes: Vec::new(),
            patches: Vec::new(),
            drains: Vec::new(),
            statics: Vec::new(),
            lidar_parked: Vec::new(),
            satellite_parked: Vec::new(),
            camera_parked: Vec::new(),
            f_rough: Field::new(seed ^ 0x11, 0.35),
            f_bump: Field::new(seed ^ 0x12, 1.7),
            f_crack: Field::new(seed ^ 0x13, 2.5),
            f_crack_mask: Field::new(seed ^ 0x14, 9.0),
            f_wear: Field::new(seed ^ 0x15, 0.12),
        };
        w.place_features(&mut rng);
        w.place_statics(&mut rng);
        let n = rng.random_range(3..8);
        w.lidar_parked = w.parking(&mut rng, n);
        let n = rng.random_range(3..8);
        let sat = w.parking(&mut rng, n);
        w.satellite_parked = w.cars_at(&mut rng, &sat);
        let n = rng.random_range(1..4);
        let cam = w.parking(&mut rng, n);
        w.camera_parked = w.cars_at(&mut rng, &cam);
        w
    }

    fn cars_at(&self, rng: &mut ChaCha8Rng, fps: &[Footprint]) -> Vec<Solid> {
        fps.iter()
            .flat_map(|f| vehicle(rng, f.x, f.y, self.height(f.x, f.y), f.yaw))
            .collect()
    }

    /// Random road points beyond the stop bars (for patches, manholes, parking).
    fn road_point(&self, rng: &mut ChaCha8Rng, s_from: f64, s_to: f64) -> (usize, f64, f64) {
        let i = rng.random_range(0..self.approaches.len());
        let a = &self.approaches[i];
        let s = rng.random_range(a.s_stop + s_from..a.s_stop + s_to);
        let l = rng.random_range(-a.w_out + 0.3..a.w_in - 0.3);
        (i, s, l)
    }

    fn place_features(&mut self, rng: &mut ChaCha8Rng) {
        for _ in 0..rng.random_range(3..7) {
            let (i, s, l) = if rng.random_bool(0.3) {
                (0, rng.random_range(-6.0..6.0), rng.random_range(-6.0..6.0))
            } else {
                self.road_point(rng, 2.0, 55.0)
            };
            let (x, y) = self.approaches[i].point(s, l);
            if self.curb_distance(x, y).0 < -1.0 {
                self.manholes.push(Disc {
                    x,
                    y,
                    r: rng.random_range(0.3..0.4),
                    age: rng.random(),
                });
            }
        }
        for _ in 0..rng.random_range(3..9) {
            let (i, s, l) = self.road_point(rng, -8.0, 55.0);
            let (x, y) = self.approaches[i].point(s, l);
            let yaw = self.approaches[i].angle + rng.random_range(-0.1..0.1);
            let fp = Footprint {
                x,
                y,
                yaw,
                hl: rng.random_range(0.8..4.0),
                hw: rng.random_range(0.6..2.0),
            };
            self.patches.push(Rect {
                fp,
                age: rng.random(),
            });
        }
        for a in self.approaches.clone() {
            for side in [1.0, -1.0] {
                if rng.random_bool(0.6) {
                    let w = if side > 0.0 { a.w_in } else { a.w_out };
                    let s = a.s_stop + rng.random_range(1.0..25.0);
                    let (x, y) = a.point(s, side * (w - 0.35));
                    let fp = Footprint {
                        x,
                        y,
                        yaw: a.angle,
                        hl: 0.5,
                        hw: 0.3,
                    };
                    self.drains.push(Rect {
                        fp,
                        age: rng.random(),
                    });
                }
            }
        }
    }

    /// Parked cars along the curbs, beyond the stop bars.
    fn parking(&self, rng: &mut ChaCha8Rng, n: usize) -> Vec<Footprint> {
        let mut out: Vec<Footprint> = Vec::new();
        let mut tries = 0;
        while out.len() < n && tries < 200 {
            tries += 1;
            let i = rng.random_range(0..self.approaches.len());
            let a = &self.approaches[i];
            let side = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            let w = if side > 0.0 { a.w_in } else { a.w_out };
            let s = a.s_stop + rng.random_range(10.0..60.0);
            let (x, y) = a.point(s, side * (w - 1.2));
            let yaw =
                if side > 0.0 { a.angle + PI } else { a.angle } + rng.random_range(-0.03..0.03);
            let fp = Footprint {
                x,
                y,
                yaw,
                hl: 2.4,
                hw: 0.95,
            };
            if out.iter().all(|o| (o.x - x).hypot(o.y - y) > 6.0)
                && self.curb_distance(x, y).0 < -0.5
            {
                out.push(fp);
            }
        }
        out
    }

    fn place_statics(&mut self, rng: &mut ChaCha8Rng) {
        let k = self.approaches.len();
        // Buildings on each corner block, set back from the sidewalk.
        for i in 0..k {
            let c = self.corners[i];
            let a = &self.approaches[i];
            let setback = CURB_W + c.lawn_w + c.sidewalk_w + rng.random_range(3.0..10.0);
            let mut placed = 0;
            for _ in 0..40 {
                if placed >= rng.random_range(1..=3) {
                    break;
                }
                let bearing = a.angle + c.gap * rng.random_range(0.15..0.85);
                let dist = rng.random_range(22.0..60.0);
                let (cx, cy) = (dist * bearing.cos(), dist * bearing.sin());
                let hl = rng.random_range(5.0..13.0);
                let hw = rng.random_range(4.0..10.0);
                let yaw = a.angle + rng.random_range(-0.05..0.05);
                let (s, co) = yaw.sin_cos();
                let ok = [
                    (-1.0, -1.0),
                    (-1.0, 1.0),
                    (1.0, -1.0),
                    (1.0, 1.0),
                    (0.0, 0.0),
                ]
                .iter()
                .all(|&(p, q)| {
                    let x = cx + p * hl * co - q * hw * s;
                    let y = cy + p * hl * s + q * hw * co;
                    self.curb_distance(x, y).0 > setback
                }) && self.statics.iter().all(|o| {
                    let (ox, oy) = o.center_xy();
                    (ox - cx).hypot(oy - cy) > hl + hw + 8.0
                });
                if !ok {
                    continue;
                }
                let z = self.height(cx, cy);
                let roof = rng.random_range(0.15..0.5);
                let tint = rng.random_range(-0.05..0.05);
                self.statics.push(Solid::new(
                    Shape::Box {
                        cx,
                        cy,
                        z0: z - 0.5,
                        z1: z + rng.random_range(4.0..18.0),
                        hl,
                        hw,
                        yaw,
                    },
                    Kind::Building,
                    (roof, rng.random_range(0.2..0.6)),
                    ([roof + tint, roof, roof - tint], [0.55, 0.45, 0.38]),
                    rng.next_u64(),
                ));
                placed += 1;
            }
        }
        // Street trees along the lawns/sidewalks, and a signal/light pole per corner.
        for i in 0..k {
            let a = self.approaches[i].clone();
            for side in [1.0, -1.0] {
                let corner = if side > 0.0 {
                    self.corners[i]
                } else {
                    self.corners[(i + k - 1) % k]
                };
                let w = if side > 0.0 { a.w_in } else { a.w_out };
                let off = if corner.lawn_w > 1.2 {
                    CURB_W + 0.5 * corner.lawn_w
                } else {
                    CURB_W + corner.lawn_w + corner.sidewalk_w + 1.5
                };
                let mut s = a.s_stop + rng.random_range(4.0..12.0);
                while s < 70.0 {
                    if rng.random_bool(0.55) {
                        let (x, y) = a.point(s, side * (w + off));
                        let d = self.curb_distance(x, y).0;
                        let clear = self.statics.iter().all(|o| {
                            let (ox, oy) = o.center_xy();
                            (ox - x).hypot(oy - y) > 4.0 || o.kind == Kind::Trunk
                        });
                        if d > CURB_W + 0.2 && clear && !self.in_building(x, y, 3.0) {
                            self.tree(rng, x, y);
                        }
                    }
                    s += rng.random_range(8.0..15.0);
                }
                if side > 0.0 {
                    let (x, y) = a.point(self.approaches[i].s_cw - 1.0, w + CURB_W + 0.6);
                    let z = self.height(x, y);
                    self.statics.push(Solid::new(
                        Shape::Cylinder {
                            cx: x,
                            cy: y,
                            r: 0.14,
                            z0: z,
                            z1: z + rng.random_range(6.0..9.0),
                        },
                        Kind::Trunk,
                        (0.35, 0.3),
                        ([0.45, 0.45, 0.45], [0.4, 0.4, 0.4]),
                        rng.next_u64(),
                    ));
                }
            }
        }
    }

    fn in_building(&self, x: f64, y: f64, margin: f64) -> bool {
        self.statics.iter().any(|o| match (o.kind, o.shape) {
            (
                Kind::Building,
                Shape::Box {
                    cx,
                    cy,
                    hl,
                    hw,
                    yaw,
                    ..
                },
            ) => Footprint {
                x: cx,
                y: cy,
                yaw,
                hl,
                hw,
            }
            .contains(x, y, margin),
            _ => false,
        })
    }

    fn tree(&mut self, rng: &mut ChaCha8Rng, x: f64, y: f64) {
        let z = self.height(x, y);
        let r = rng.random_range(1.8..3.6);
        let zc = z + r + rng.random_range(2.0..4.5);
        let leaf = rng.random_range(0.06..0.12);
        let tex = rng.next_u64();
        self.statics.push(Solid::new(
            Shape::Cylinder {
                cx: x,
                cy: y,
                r: rng.random_range(0.12..0.25),
                z0: z,
                z1: zc,
            },
            Kind::Trunk,
            (0.12, 0.1),
            ([0.25, 0.2, 0.15], [0.2, 0.16, 0.12]),
            tex,
        ));
        self.statics.push(Solid::new(
            Shape::Sphere {
                c: [
                    x + rng.random_range(-0.5..0.5),
                    y + rng.random_range(-0.5..0.5),
                    zc,
                ],
                r,
            },
            Kind::Crown,
            (leaf, leaf * 0.8),
            ([0.10, 0.17 + leaf, 0.07], [0.08, 0.14, 0.06]),
            tex ^ 7,
        ));
    }

    /// Remove trees whose crown would hang around the camera (poles are placed clear of them).
    pub(crate) fn clear_around(&mut self, x: f64, y: f64, radius: f64) {
        let near: Vec<(f64, f64)> = self
            .statics
            .iter()
            .filter(|o| o.kind == Kind::Crown)
            .filter(|o| {
                let (ox, oy) = o.center_xy();
                let r = match o.shape {
                    Shape::Sphere { r, .. } => r,
                    _ => 0.0,
                };
                (ox - x).hypot(oy - y) < radius + r
            })
            .map(|o| o.center_xy())
            .collect();
        self.statics.retain(|o| {
            let (ox, oy) = o.center_xy();
            !((o.kind == Kind::Crown || o.kind == Kind::Trunk)
                && near.iter().any(|&(nx, ny)| (nx - ox).hypot(ny - oy) < 1.0))
        });
    }

    /// Signed distance from the curb (negative on the road) and the corner index.
    #[inline]
    pub(crate) fn curb_distance(&self, x: f64, y: f64) -> (f64, usize) {
        let k = self.approaches.len();
        let theta = y.atan2(x).rem_euclid(TAU);
        // Sector i spans [angle_i, angle_{i+1}); the last wraps round.
        let mut i = k - 1;
        for j in 0..k {
            let next = if j + 1 < k {
                self.approaches[j + 1].angle
            } else {
                self.approaches[0].angle + TAU
            };
            let t = if theta < self.approaches[j].angle {
                theta + TAU
            } else {
                theta
            };
            if t >= self.approaches[j].angle && t < next {
                i = j;
                break;
            }
        }
        let ai = &self.approaches[i];
        let aj = &self.approaches[(i + 1) % k];
        let c = &self.corners[i];
        let a = ai.local(x, y).1 - ai.w_in;
        let b = -aj.local(x, y).1 - aj.w_out;
        let d = if c.gap < PI {
            let r = c.radius;
            if a < r || b < r {
                r - (r - a).max(0.0).hypot((r - b).max(0.0))
            } else {
                a.min(b)
            }
        } else {
            a.max(b)
        };
        (d, i)
    }

    /// Height of the sloped base plane.
    #[inline]
    pub(crate) fn base(&self, x: f64, y: f64) -> f64 {
        self.z0 + self.grad[0] * x + self.grad[1] * y
    }

    /// Ground height at (x, y): base plane + crown / curb / sidewalk rise + roughness. Always
    /// within [`DETAIL_MIN`, `DETAIL_MAX`] of [`World::base`].
    #[inline]
    pub(crate) fn height(&self, x: f64, y: f64) -> f64 {
        let (d, _) = self.curb_distance(x, y);
        self.base(x, y) + self.detail(x, y, d)
    }

    #[inline]
    fn detail(&self, x: f64, y: f64, d: f64) -> f64 {
        if d < 0.0 {
            let mut h = self.crown * smoothstep(0.0, CROWN_RUN, -d) + 0.002 * self.f_rough.at(x, y);
            for m in &self.manholes {
                let q = (x - m.x).hypot(y - m.y);
                if q < m.r {
                    h -= 0.008;
                }
            }
            h
        } else if d < CURB_RAMP {
            self.curb_h * smoothstep(0.0, CURB_RAMP, d)
        } else {
            let rise = SIDE_SLOPE * (d - CURB_W).clamp(0.0, SIDE_SLOPE_RUN);
            let bump = 0.02 * smoothstep(CURB_W, CURB_W + 1.0, d) * self.f_bump.at(x, y);
            self.curb_h + rise + bump
        }
    }

    /// Material and paint at (x, y).
    pub(crate) fn surface(&self, x: f64, y: f64) -> Surface {
        let (d, corner) = self.curb_distance(x, y);
        let mk = |mat, wear| Surface {
            mat,
            wear,
            d_curb: d,
        };
        if d >= 0.0 {
            let c = &self.corners[corner];
            return if d < CURB_W {
                mk(Material::Curb, 0.0)
            } else if d < CURB_W + c.lawn_w {
                mk(Material::Grass, 0.0)
            } else if d < CURB_W + c.lawn_w + c.sidewalk_w {
                mk(Material::Sidewalk, 0.0)
            } else {
                mk(Material::Grass, 0.5)
            };
        }
        for a in &self.approaches {
            let (s, l) = a.local(x, y);
            if let Some((paint, wear)) = a.paint(s, l) {
                // Worn paint flakes off in specks: local wear is the feature's wear modulated by
                // fine noise, and completely flaked-off specks show the asphalt underneath.
                let local = (wear + 0.35 * self.f_wear.at(x, y)).clamp(0.0, 1.0);
                if local < 0.85 {
                    let mat = match paint {
                        Paint::White => Material::PaintWhite,
                        Paint::Yellow => Material::PaintYellow,
                    };
                    return mk(mat, local);
                }
            }
        }
        for m in &self.manholes {
            if (x - m.x).hypot(y - m.y) < m.r {
                return mk(Material::Manhole, m.age);
            }
        }
        for r in &self.drains {
            if r.fp.contains(x, y, 0.0) {
                return mk(Material::Drain, r.age);
            }
        }
        // Zero contours of a fractal field, domain-warped at 10–20 cm so they run jagged.
        let crack_on = self.f_crack_mask.at(x, y) > 0.25 && {
            let (wx, wy) = (
                self.f_wear.at(y * 1.7, x * 1.7),
                self.f_wear.at(x * 1.9 + 40.0, y * 1.9),
            );
            self.f_crack.fbm(x + 0.12 * wx, y + 0.12 * wy, 3).abs() < 0.008
        };
        if crack_on {
            return mk(Material::Crack, 0.0);
        }
        for r in &self.patches {
            if r.fp.contains(x, y, 0.0) {
                return mk(Material::Patch, r.age);
            }
        }
        mk(Material::Asphalt, 0.0)
    }

    /// All control-point candidates: (id, local x, local y). Their z is [`World::height`].
    pub(crate) fn control_candidates(&self) -> Vec<(String, f64, f64)> {
        let mut out = Vec::new();
        for a in &self.approaches {
            for m in &a.marks {
                for (v, (p, &c)) in m.poly.iter().zip(&m.control).enumerate() {
                    if c {
                        let (x, y) = a.point(p[0], p[1]);
                        out.push((format!("{}-{v}", m.id), x, y));
                    }
                }
            }
        }
        out
    }
}

/// Stop bar, crosswalk bars and lane arrows of approach `idx`.
fn build_marks(a: &mut Approach, idx: usize, rng: &mut ChaCha8Rng) {
    let in_w = a.lanes_in as f64 * a.lane_w;
    let out_w = a.lanes_out as f64 * a.lane_w;
    let rect = |s0: f64, s1: f64, l0: f64, l1: f64| vec![[s0, l0], [s1, l0], [s1, l1], [s0, l1]];
    let wear = |rng: &mut ChaCha8Rng| rng.random_range(0.0..0.55);
    let w = wear(rng);
    a.marks.push(Mark::new(
        format!("a{idx}-stop"),
        Paint::White,
        w,
        rect(
            a.s_stop,
            a.s_stop + STOP_BAR_W,
            DOUBLE_YELLOW_OFFSET + 0.2,
            in_w,
        ),
        vec![true; 4],
    ));
    if a.crosswalk {
        let w = wear(rng);
        let mut l = -out_w + 0.1;
        let mut bar = 0;
        while l + ZEBRA_BAR <= in_w - 0.1 {
            a.marks.push(Mark::new(
                format!("a{idx}-zebra{bar}"),
                Paint::White,
                (w + rng.random_range(-0.1..0.1)).clamp(0.0, 0.8),
                rect(a.s_cw, a.s_cw + CROSSWALK_DEPTH, l, l + ZEBRA_BAR),
                vec![true; 4],
            ));
            l += 2.0 * ZEBRA_BAR;
            bar += 1;
        }
    }
    // Arrows point towards the centre (decreasing s); the inbound driver's left is −l.
    for lane in 0..a.lanes_in {
        if !rng.random_bool(0.7) {
            continue;
        }
        let lc = (lane as f64 + 0.5) * a.lane_w;
        let tip = a.s_stop + rng.random_range(4.0..7.0);
        let kind = if a.lanes_in == 1 {
            rng.random_range(0..3)
        } else if lane == 0 {
            1 // leftmost inbound lane (next to the centre line): left turn
        } else {
            rng.random_range(0..3).min(1) * 2 // straight or right
        };
        let w = wear(rng);
        let id = format!("a{idx}-arrow{lane}");
        const HEAD_L: f64 = 1.4;
        const HEAD_HW: f64 = 0.5;
        const SHAFT_HW: f64 = 0.13;
        const TAIL: f64 = 5.0;
        match kind {
            0 => {
                a.marks.push(Mark::new(
                    format!("{id}-head"),
                    Paint::White,
                    w,
                    vec![
                        [tip, lc],
                        [tip + HEAD_L, lc + HEAD_HW],
                        [tip + HEAD_L, lc - HEAD_HW],
                    ],
                    vec![true; 3],
                ));
                a.marks.push(Mark::new(
                    format!("{id}-shaft"),
                    Paint::White,
                    w,
                    rect(tip + HEAD_L, tip + TAIL, lc - SHAFT_HW, lc + SHAFT_HW),
                    vec![false, true, true, false],
                ));
            }
            _ => {
                // Turn arrow: shaft, a sideways arm at the front, and a head pointing sideways.
                let dir = if kind == 1 { -1.0 } else { 1.0 };
                let arm_s0 = tip + 0.3;
                let arm_s1 = arm_s0 + 2.0 * SHAFT_HW;
                let arm_end = lc + dir * 0.9;
                a.marks.push(Mark::new(
                    format!("{id}-shaft"),
                    Paint::White,
                    w,
                    rect(arm_s0, tip + TAIL, lc - SHAFT_HW, lc + SHAFT_HW),
                    vec![true, true, true, true],
                ));
                let (l0, l1) = if dir < 0.0 {
                    (arm_end, lc - SHAFT_HW)
                } else {
                    (lc + SHAFT_HW, arm_end)
                };
                a.marks.push(Mark::new(
                    format!("{id}-arm"),
                    Paint::White,
                    w,
                    rect(arm_s0, arm_s1, l0, l1),
                    vec![false; 4],
                ));
                let sm = 0.5 * (arm_s0 + arm_s1);
                let head = if dir < 0.0 {
                    vec![
                        [sm, arm_end - HEAD_L],
                        [sm + HEAD_HW, arm_end],
                        [sm - HEAD_HW, arm_end],
                    ]
                } else {
                    vec![
                        [sm, arm_end + HEAD_L],
                        [sm - HEAD_HW, arm_end],
                        [sm + HEAD_HW, arm_end],
                    ]
                };
                a.marks.push(Mark::new(
                    format!("{id}-head"),
                    Paint::White,
                    w,
                    head,
                    vec![true; 3],
                ));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn height_stays_in_detail_bounds_and_curb_steps() {
        for seed in 0..4 {
            let w = World::generate(seed);
            for i in 0..20000 {
                let x = (i % 200) as f64 * 0.61 - 61.0;
                let y = (i / 200) as f64 * 1.23 - 61.0;
                let d = w.height(x, y) - w.base(x, y);
                assert!(
                    (DETAIL_MIN..=DETAIL_MAX).contains(&d),
                    "seed {seed} ({x},{y}): {d}"
                );
            }
            // Walking out along the bisector of corner 0 crosses a curb: a 10–20 cm step.
            let a0 = w.approaches[0].angle + 0.5 * w.corners[0].gap;
            let hs: Vec<f64> = (0..4000)
                .map(|i| {
                    let r = i as f64 * 0.01;
                    let (x, y) = (r * a0.cos(), r * a0.sin());
                    w.height(x, y) - w.base(x, y)
                })
                .collect();
            // Largest rise over 4 cm (the face is a 2 cm ramp).
            let step = hs.windows(5).map(|v| v[4] - v[0]).fold(0.0f64, f64::max);
            assert!(step > 0.09 && step < 0.21, "seed {seed}: step {step}");
        }
    }

    #[test]
    fn centre_is_road_and_markings_exist() {
        let w = World::generate(3);
        assert!(w.curb_distance(0.0, 0.0).0 < -2.0);
        let a = &w.approaches[0];
        let stop = &a.marks[0];
        let c = stop.poly.iter().fold([0.0, 0.0], |acc, p| {
            [acc[0] + p[0] / 4.0, acc[1] + p[1] / 4.0]
        });
        let (x, y) = a.point(c[0], c[1]);
        let s = w.surface(x, y);
        assert!(
            matches!(s.mat, Material::PaintWhite | Material::Asphalt),
            "{s:?}"
        );
        // Most of a stop bar is paint.
        let mut paint = 0;
        for i in 0..100 {
            let t = i as f64 / 100.0;
            let (x, y) = a.point(
                c[0],
                stop.poly[0][1] + t * (stop.poly[2][1] - stop.poly[0][1]),
            );
            paint += (w.surface(x, y).mat == Material::PaintWhite) as usize;
        }
        assert!(paint > 40, "{paint}");
        assert!(w.control_candidates().len() >= 8);
    }
}
