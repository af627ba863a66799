//! The camera models' projection with its analytic Jacobian, in f64, for the smooth estimator
//! ([`super::Smooth`]): the pixel of a camera-frame point and ∂(u, v)/∂(point).

// Small fixed-size matrices (2×3) indexed by row and column read as the formulas do.
#![allow(clippy::needless_range_loop)]

use crate::camera::Camera;
use crate::localize::mi::kernel::FastCamera;

/// The camera's projection with its analytic Jacobian, in f64.
#[derive(Debug, Clone, Copy)]
pub(super) enum Proj {
    Mei {
        /// fx, fy, skew, cx, cy.
        k: [f64; 5],
        xi: f64,
        /// k1, k2, p1, p2.
        d: [f64; 4],
        zmin: f64,
        r2max: f64,
    },
    Equidistant {
        /// fx, fy, alpha, cx, cy.
        k: [f64; 5],
        /// k1..k4.
        d: [f64; 4],
        theta_max: f64,
    },
}

/// On the forward axis the equidistant model's θ_d/ρ tends to 1/z (the camera's own branch).
const AXIS_EPS: f64 = 1e-12;

impl Proj {
    pub(super) fn new(cam: &Camera) -> Self {
        // The validity limits are the fast kernel's (the same model limits, computed once).
        match (cam, FastCamera::new(cam, 0)) {
            (Camera::Mei(m), FastCamera::Mei(f)) => Proj::Mei {
                k: [m.fx, m.fy, m.skew, m.cx, m.cy],
                xi: m.xi,
                d: [m.k1, m.k2, m.p1, m.p2],
                zmin: f.zmin as f64,
                r2max: f.r2max as f64,
            },
            (Camera::Equidistant(e), FastCamera::Equidistant(f)) => Proj::Equidistant {
                k: [e.fx, e.fy, e.alpha, e.cx, e.cy],
                d: [e.k1, e.k2, e.k3, e.k4],
                theta_max: f.theta_max as f64,
            },
            // `FastCamera::new` keeps the model: unreachable, but answered as "not visible".
            _ => Proj::Equidistant {
                k: [0.0; 5],
                d: [0.0; 4],
                theta_max: -1.0,
            },
        }
    }

    /// Pixel (u, v) of camera-frame point `p` and ∂(u, v)/∂p (rows), or `None` when the model
    /// does not see it.
    #[inline]
    pub(super) fn project(&self, p: [f64; 3]) -> Option<([f64; 2], [[f64; 3]; 2])> {
        self.project_with::<true>(p)
    }

    /// [`Self::project`]'s pixel alone (the Jacobian's rows are zeros): the same arithmetic, so
    /// the same pixel to the last bit, for the passes that need no gradient.
    #[inline]
    pub(super) fn project_uv(&self, p: [f64; 3]) -> Option<[f64; 2]> {
        self.project_with::<false>(p).map(|(uv, _)| uv)
    }

    #[inline]
    fn project_with<const JAC: bool>(&self, p: [f64; 3]) -> Option<([f64; 2], [[f64; 3]; 2])> {
        match *self {
            Proj::Mei {
                k,
                xi,
                d,
                zmin,
                r2max,
            } => {
                let n = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                if !(n > 0.0 && n.is_finite()) {
                    return None;
                }
                let s = [p[0] / n, p[1] / n, p[2] / n];
                if s[2] <= zmin {
                    return None;
                }
                let den = s[2] + xi;
                let (x, y) = (s[0] / den, s[1] / den);
                let r2 = x * x + y * y;
                if r2 >= r2max {
                    return None;
                }
                let [k1, k2, p1, p2] = d;
                let radial = 1.0 + k1 * r2 + k2 * r2 * r2;
                let xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
                let yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
                let u = k[0] * xd + k[2] * yd + k[3];
                let v = k[1] * yd + k[4];
                if !JAC {
                    return Some(([u, v], [[0.0; 3]; 2]));
                }
                // ∂(xd, yd)/∂(x, y).
                let dr = k1 + 2.0 * k2 * r2; // ∂radial/∂r² / 1
                let (drx, dry) = (2.0 * x * dr, 2.0 * y * dr);
                let a = radial + x * drx + 2.0 * p1 * y + 6.0 * p2 * x;
                let b = x * dry + 2.0 * p1 * x + 2.0 * p2 * y;
                let c = y * drx + 2.0 * p1 * x + 2.0 * p2 * y;
                let e = radial + y * dry + 6.0 * p1 * y + 2.0 * p2 * x;
                // ∂(x, y)/∂s, then ∂s/∂p = (I − s sᵀ)/n.
                let dxs = [1.0 / den, 0.0, -x / den];
                let dys = [0.0, 1.0 / den, -y / den];
                let mut dxp = [0.0; 3];
                let mut dyp = [0.0; 3];
                for j in 0..3 {
                    let mut gx = 0.0;
                    let mut gy = 0.0;
                    for i in 0..3 {
                        let m = (if i == j { 1.0 } else { 0.0 } - s[i] * s[j]) / n;
                        gx += dxs[i] * m;
                        gy += dys[i] * m;
                    }
                    dxp[j] = gx;
                    dyp[j] = gy;
                }
                let mut ju = [0.0; 3];
                let mut jv = [0.0; 3];
                for j in 0..3 {
                    let dxd = a * dxp[j] + b * dyp[j];
                    let dyd = c * dxp[j] + e * dyp[j];
                    ju[j] = k[0] * dxd + k[2] * dyd;
                    jv[j] = k[1] * dyd;
                }
                Some(([u, v], [ju, jv]))
            }
            Proj::Equidistant { k, d, theta_max } => {
                if !(p.iter().all(|v| v.is_finite())) {
                    return None;
                }
                let rho2 = p[0] * p[0] + p[1] * p[1];
                let rho = rho2.sqrt();
                if rho2 + p[2] * p[2] == 0.0 {
                    return None;
                }
                let t = rho.atan2(p[2]);
                if t >= theta_max {
                    return None;
                }
                let (x, y, jx, jy);
                if p[2] > 0.0 && rho < AXIS_EPS * p[2] {
                    x = p[0] / p[2];
                    y = p[1] / p[2];
                    jx = [1.0 / p[2], 0.0, -x / p[2]];
                    jy = [0.0, 1.0 / p[2], -y / p[2]];
                } else {
                    let [k1, k2, k3, k4] = d;
                    let t2 = t * t;
                    let td = t * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))));
                    let s = td / rho;
                    x = p[0] * s;
                    y = p[1] * s;
                    if !JAC {
                        let u = k[0] * (x + k[2] * y) + k[3];
                        return Some(([u, k[1] * y + k[4]], [[0.0; 3]; 2]));
                    }
                    let dtd =
                        1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)));
                    // θ = atan2(ρ, z): ∂θ/∂p = (z·p_x/ρ, z·p_y/ρ, −ρ) / (ρ² + z²).
                    let q = rho2 + p[2] * p[2];
                    let dt = [p[2] * p[0] / rho / q, p[2] * p[1] / rho / q, -rho / q];
                    let drho = [p[0] / rho, p[1] / rho, 0.0];
                    // s = θ_d(θ)/ρ.
                    let mut ds = [0.0; 3];
                    for j in 0..3 {
                        ds[j] = (dtd * dt[j] * rho - td * drho[j]) / rho2;
                    }
                    jx = [s + p[0] * ds[0], p[0] * ds[1], p[0] * ds[2]];
                    jy = [p[1] * ds[0], s + p[1] * ds[1], p[1] * ds[2]];
                }
                let u = k[0] * (x + k[2] * y) + k[3];
                let v = k[1] * y + k[4];
                let ju = [
                    k[0] * (jx[0] + k[2] * jy[0]),
                    k[0] * (jx[1] + k[2] * jy[1]),
                    k[0] * (jx[2] + k[2] * jy[2]),
                ];
                let jv = [k[1] * jy[0], k[1] * jy[1], k[1] * jy[2]];
                Some(([u, v], [ju, jv]))
            }
        }
    }
}
