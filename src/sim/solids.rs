//! 3-D solids standing on the ground (buildings, tree trunks and crowns, vehicles, pedestrians) and
//! their ray intersections. Every sensor that can see an object — satellite, fisheye, shadow rays —
//! uses these same intersections, so occlusion and parallax are consistent between views.

use nalgebra::Vector3;

/// Geometry of a solid (local map frame, metres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shape {
    /// Box with vertical sides, rotated by `yaw` about z: half-extents `hl` (along yaw) and `hw`.
    Box {
        /// Centre x.
        cx: f64,
        /// Centre y.
        cy: f64,
        /// Bottom z.
        z0: f64,
        /// Top z.
        z1: f64,
        /// Half length along the yaw direction.
        hl: f64,
        /// Half width across it.
        hw: f64,
        /// Heading, radians from +x.
        yaw: f64,
    },
    /// Vertical cylinder.
    Cylinder {
        /// Axis x.
        cx: f64,
        /// Axis y.
        cy: f64,
        /// Radius.
        r: f64,
        /// Bottom z.
        z0: f64,
        /// Top z.
        z1: f64,
    },
    /// Sphere (tree crowns).
    Sphere {
        /// Centre.
        c: [f64; 3],
        /// Radius.
        r: f64,
    },
}

/// What a solid is: decides its surface appearance.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// Building: roof on top, façade on the sides.
    Building,
    /// Tree trunk.
    Trunk,
    /// Tree crown (leafy, lets some light through).
    Crown,
    /// Car/truck body.
    VehicleBody,
    /// Car cabin: roof on top, glass on the sides.
    VehicleCabin,
    /// Pedestrian.
    Pedestrian,
    /// Road sign plate (retroreflective sheeting: the brightest LiDAR return).
    Sign,
}

/// A solid with its appearance in each band.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Solid {
    /// Geometry.
    pub shape: Shape,
    /// Kind.
    pub kind: Kind,
    /// Visible-band (fisheye) albedo of the top surface, 0..1.
    pub gray_top: f64,
    /// Visible-band albedo of the sides.
    pub gray_side: f64,
    /// Satellite RGB albedo of the top surface (what the satellite mostly sees).
    pub rgb_top: [f64; 3],
    /// Satellite RGB of the sides.
    pub rgb_side: [f64; 3],
    /// Per-solid texture seed.
    pub tex: u64,
    bound_c: Vector3<f64>,
    bound_r2: f64,
}

/// A ray hit.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Hit {
    /// Ray parameter (distance for unit rays).
    pub t: f64,
    /// Outward unit normal.
    pub normal: Vector3<f64>,
}

impl Solid {
    /// A solid; the bounding sphere is computed here.
    pub(crate) fn new(
        shape: Shape,
        kind: Kind,
        gray: (f64, f64),
        rgb: ([f64; 3], [f64; 3]),
        tex: u64,
    ) -> Self {
        let (c, r) = match shape {
            Shape::Box {
                cx,
                cy,
                z0,
                z1,
                hl,
                hw,
                ..
            } => {
                let hz = 0.5 * (z1 - z0);
                (
                    Vector3::new(cx, cy, z0 + hz),
                    (hl * hl + hw * hw + hz * hz).sqrt(),
                )
            }
            Shape::Cylinder { cx, cy, r, z0, z1 } => {
                let hz = 0.5 * (z1 - z0);
                (Vector3::new(cx, cy, z0 + hz), (r * r + hz * hz).sqrt())
            }
            Shape::Sphere { c, r } => (Vector3::new(c[0], c[1], c[2]), r),
        };
        Solid {
            shape,
            kind,
            gray_top: gray.0,
            gray_side: gray.1,
            rgb_top: rgb.0,
            rgb_side: rgb.1,
            tex,
            bound_c: c,
            bound_r2: r * r * 1.0001 + 1e-9,
        }
    }

    /// Horizontal centre of the solid.
    pub(crate) fn center_xy(&self) -> (f64, f64) {
        (self.bound_c.x, self.bound_c.y)
    }

    /// Top height of the solid.
    pub fn top(&self) -> f64 {
        match self.shape {
            Shape::Box { z1, .. } | Shape::Cylinder { z1, .. } => z1,
            Shape::Sphere { c, r } => c[2] + r,
        }
    }

    /// First intersection of the ray `o + t·d` (d unit) with `t_min < t < t_max`.
    #[inline]
    pub(crate) fn intersect(
        &self,
        o: &Vector3<f64>,
        d: &Vector3<f64>,
        t_min: f64,
        t_max: f64,
    ) -> Option<Hit> {
        // Bounding-sphere rejection: most rays miss most solids.
        let oc = self.bound_c - o;
        let tc = oc.dot(d);
        let dist2 = oc.norm_squared() - tc * tc;
        if dist2 > self.bound_r2 {
            return None;
        }
        let half = (self.bound_r2 - dist2).max(0.0).sqrt();
        if tc + half < t_min || tc - half > t_max {
            return None;
        }
        let hit = match self.shape {
            Shape::Box {
                cx,
                cy,
                z0,
                z1,
                hl,
                hw,
                yaw,
            } => {
                let (s, c) = yaw.sin_cos();
                // Into box coordinates (a along yaw, b across).
                let (px, py) = (o.x - cx, o.y - cy);
                let oa = [c * px + s * py, -s * px + c * py, o.z];
                let da = [c * d.x + s * d.y, -s * d.x + c * d.y, d.z];
                let lo = [-hl, -hw, z0];
                let hi = [hl, hw, z1];
                let (mut tn, mut tf) = (f64::NEG_INFINITY, f64::INFINITY);
                let mut axis = 0usize;
                let mut sign = 1.0;
                for k in 0..3 {
                    if da[k].abs() < 1e-300 {
                        if oa[k] < lo[k] || oa[k] > hi[k] {
                            return None;
                        }
                        continue;
                    }
                    let inv = 1.0 / da[k];
                    let (mut t0, mut t1) = ((lo[k] - oa[k]) * inv, (hi[k] - oa[k]) * inv);
                    let mut sg = -1.0;
                    if t0 > t1 {
                        std::mem::swap(&mut t0, &mut t1);
                        sg = 1.0;
                    }
                    if t0 > tn {
                        tn = t0;
                        axis = k;
                        sign = sg;
                    }
                    tf = tf.min(t1);
                }
                if tn > tf || tn <= t_min || tn >= t_max {
                    return None;
                }
                let n = match axis {
                    0 => Vector3::new(c * sign, s * sign, 0.0),
                    1 => Vector3::new(-s * sign, c * sign, 0.0),
                    _ => Vector3::new(0.0, 0.0, sign),
                };
                Hit { t: tn, normal: n }
            }
            Shape::Cylinder { cx, cy, r, z0, z1 } => {
                let (px, py) = (o.x - cx, o.y - cy);
                let mut best: Option<Hit> = None;
                // Side.
                let a = d.x * d.x + d.y * d.y;
                if a > 1e-300 {
                    let b = px * d.x + py * d.y;
                    let cc = px * px + py * py - r * r;
                    let disc = b * b - a * cc;
                    if disc >= 0.0 {
                        let t = (-b - disc.sqrt()) / a;
                        let z = o.z + t * d.z;
                        if t > t_min && t < t_max && z >= z0 && z <= z1 {
                            let n = Vector3::new(px + t * d.x, py + t * d.y, 0.0) / r;
                            best = Some(Hit { t, normal: n });
                        }
                    }
                }
                // Top cap (rays from above).
                if d.z < 0.0 {
                    let t = (z1 - o.z) / d.z;
                    let (x, y) = (px + t * d.x, py + t * d.y);
                    if t > t_min
                        && t < t_max
                        && x * x + y * y <= r * r
                        && best.is_none_or(|h| t < h.t)
                    {
                        best = Some(Hit {
                            t,
                            normal: Vector3::z(),
                        });
                    }
                }
                best?
            }
            Shape::Sphere { c, r } => {
                let oc = o - Vector3::new(c[0], c[1], c[2]);
                let b = oc.dot(d);
                let disc = b * b - (oc.norm_squared() - r * r);
                if disc < 0.0 {
                    return None;
                }
                let t = -b - disc.sqrt();
                if t <= t_min || t >= t_max {
                    return None;
                }
                Hit {
                    t,
                    normal: (oc + t * d) / r,
                }
            }
        };
        Some(hit)
    }
}

/// Nearest hit among `solids`: (index, hit).
#[inline]
pub(crate) fn nearest(
    solids: &[Solid],
    o: &Vector3<f64>,
    d: &Vector3<f64>,
    t_max: f64,
) -> Option<(usize, Hit)> {
    let mut best: Option<(usize, Hit)> = None;
    let mut tm = t_max;
    for (i, s) in solids.iter().enumerate() {
        if let Some(h) = s.intersect(o, d, 1e-6, tm) {
            tm = h.t;
            best = Some((i, h));
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plain(shape: Shape) -> Solid {
        Solid::new(shape, Kind::Building, (0.5, 0.5), ([0.5; 3], [0.5; 3]), 0)
    }

    #[test]
    fn rotated_box_top_and_side() {
        let b = plain(Shape::Box {
            cx: 10.0,
            cy: 5.0,
            z0: 0.0,
            z1: 3.0,
            hl: 2.0,
            hw: 1.0,
            yaw: 0.5,
        });
        // Straight down onto the centre: hits the top at z = 3.
        let h = b
            .intersect(&Vector3::new(10.0, 5.0, 10.0), &-Vector3::z(), 0.0, 100.0)
            .unwrap();
        assert!((h.t - 7.0).abs() < 1e-12 && (h.normal.z - 1.0).abs() < 1e-12);
        // Horizontally along the box's long axis from outside: hits the end face at distance 8 − 2.
        let (s, c) = 0.5f64.sin_cos();
        let o = Vector3::new(10.0 - 8.0 * c, 5.0 - 8.0 * s, 1.0);
        let h = b
            .intersect(&o, &Vector3::new(c, s, 0.0), 0.0, 100.0)
            .unwrap();
        assert!((h.t - 6.0).abs() < 1e-9, "{}", h.t);
        assert!((h.normal - Vector3::new(-c, -s, 0.0)).norm() < 1e-12);
        // Corner miss: a ray just outside the half width.
        let o = Vector3::new(10.0 - 1.01 * s - 8.0 * c, 5.0 + 1.01 * c - 8.0 * s, 1.0);
        assert!(b
            .intersect(&o, &Vector3::new(c, s, 0.0), 0.0, 100.0)
            .is_none());
    }

    #[test]
    fn cylinder_and_sphere() {
        let cy = plain(Shape::Cylinder {
            cx: 0.0,
            cy: 0.0,
            r: 0.5,
            z0: 0.0,
            z1: 2.0,
        });
        let h = cy
            .intersect(&Vector3::new(-5.0, 0.0, 1.0), &Vector3::x(), 0.0, 100.0)
            .unwrap();
        assert!((h.t - 4.5).abs() < 1e-12);
        assert!(cy
            .intersect(&Vector3::new(-5.0, 0.0, 2.5), &Vector3::x(), 0.0, 100.0)
            .is_none());
        let h = cy
            .intersect(&Vector3::new(0.1, 0.0, 5.0), &-Vector3::z(), 0.0, 100.0)
            .unwrap();
        assert!((h.t - 3.0).abs() < 1e-12);
        let sp = plain(Shape::Sphere {
            c: [0.0, 0.0, 5.0],
            r: 2.0,
        });
        let h = sp
            .intersect(&Vector3::new(0.0, 0.0, 20.0), &-Vector3::z(), 0.0, 100.0)
            .unwrap();
        assert!((h.t - 13.0).abs() < 1e-12);
        // t_max before the sphere: no hit.
        assert!(sp
            .intersect(&Vector3::new(0.0, 0.0, 20.0), &-Vector3::z(), 0.0, 12.0)
            .is_none());
    }
}
