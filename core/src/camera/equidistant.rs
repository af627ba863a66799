//! Equidistant fisheye model, the formula of `cv::fisheye::projectPoints` — except that the angle
//! from the axis is `atan2(ρ, z)`, not OpenCV's `atan(ρ/z)`, so rays beyond 90° (a 185° lens) map
//! correctly. For z > 0 the two agree to rounding.

use super::{CameraModel, Reject, UNDISTORT_MAX_ITER, UNDISTORT_TOL};
use nalgebra::{Point2, Unit, Vector3};
use serde::{Deserialize, Serialize};

/// Equidistant fisheye: θ_d = θ(1 + k1θ² + k2θ⁴ + k3θ⁶ + k4θ⁸).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", deny_unknown_fields)]
pub struct Equidistant {
    /// Image width (px).
    pub width: u32,
    /// Image height (px).
    pub height: u32,
    /// Focal length x (px).
    pub fx: f64,
    /// Focal length y (px).
    pub fy: f64,
    /// Principal point x (px).
    pub cx: f64,
    /// Principal point y (px).
    pub cy: f64,
    /// OpenCV fisheye skew coefficient α (dimensionless: u = fx(x + αy) + cx).
    #[serde(default)]
    pub alpha: f64,
    /// θ³ coefficient.
    #[serde(default)]
    pub k1: f64,
    /// θ⁵ coefficient.
    #[serde(default)]
    pub k2: f64,
    /// θ⁷ coefficient.
    #[serde(default)]
    pub k3: f64,
    /// θ⁹ coefficient.
    #[serde(default)]
    pub k4: f64,
    /// Lens field of view in degrees (full angle), if known; limits the valid image circle.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fov_deg: Option<f64>,
    /// Memo of the monotonic-θ limit (derived from k1..k4; build with `Default::default()`).
    #[serde(skip)]
    pub cache: LimitCache,
}

/// Lazily computed θ limit. Compares equal always: it is derived data, not a parameter.
/// Mutating k1..k4 after first use would make it stale, so treat a model as immutable once used.
#[derive(Debug, Clone, Default)]
pub struct LimitCache(std::sync::OnceLock<f64>);

impl PartialEq for LimitCache {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

/// Smallest ρ below which the direction is taken as the optical axis.
const AXIS_EPS: f64 = 1e-12;

impl Equidistant {
    #[inline]
    fn theta_d(&self, t: f64) -> f64 {
        let t2 = t * t;
        t * (1.0 + t2 * (self.k1 + t2 * (self.k2 + t2 * (self.k3 + t2 * self.k4))))
    }

    #[inline]
    fn dtheta_d(&self, t: f64) -> f64 {
        let t2 = t * t;
        1.0 + t2
            * (3.0 * self.k1 + t2 * (5.0 * self.k2 + t2 * (7.0 * self.k3 + t2 * 9.0 * self.k4)))
    }

    /// Largest θ (≤ π) up to which θ_d is strictly increasing (memoised).
    fn theta_monotonic_limit(&self) -> f64 {
        *self.cache.0.get_or_init(|| self.compute_theta_limit())
    }

    /// Scan then bisect for the first zero of dθ_d/dθ.
    fn compute_theta_limit(&self) -> f64 {
        let n = 2000;
        let mut prev = 0.0;
        for i in 1..=n {
            let t = std::f64::consts::PI * i as f64 / n as f64;
            if self.dtheta_d(t) <= 0.0 {
                let (mut lo, mut hi) = (prev, t);
                for _ in 0..60 {
                    let mid = 0.5 * (lo + hi);
                    if self.dtheta_d(mid) > 0.0 {
                        lo = mid
                    } else {
                        hi = mid
                    }
                }
                return lo;
            }
            prev = t;
        }
        std::f64::consts::PI
    }
}

impl CameraModel for Equidistant {
    fn width(&self) -> u32 {
        self.width
    }
    fn height(&self) -> u32 {
        self.height
    }

    fn project(&self, p: &Vector3<f64>) -> Result<Point2<f64>, Reject> {
        if !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()) || p.norm() == 0.0 {
            return Err(Reject::Degenerate);
        }
        let rho = (p.x * p.x + p.y * p.y).sqrt();
        let theta = rho.atan2(p.z);
        if theta >= self.theta_monotonic_limit() {
            return Err(Reject::DistortionFold);
        }
        let (x, y) = if p.z > 0.0 && rho < AXIS_EPS * p.z {
            // On the forward axis θ_d/ρ → 1/z, as in OpenCV's `cdist = 1` branch. (Near the
            // backward axis θ_d/ρ → ∞ instead, so that case must take the general formula; the
            // exact backward axis θ = π is rejected above because the limit is at most π.)
            (p.x / p.z, p.y / p.z)
        } else {
            let s = self.theta_d(theta) / rho;
            (p.x * s, p.y * s)
        };
        Ok(Point2::new(
            self.fx * (x + self.alpha * y) + self.cx,
            self.fy * y + self.cy,
        ))
    }

    fn unproject(&self, px: &Point2<f64>) -> Result<Unit<Vector3<f64>>, Reject> {
        if !(px.x.is_finite() && px.y.is_finite()) {
            return Err(Reject::Degenerate);
        }
        let y = (px.y - self.cy) / self.fy;
        let x = (px.x - self.cx) / self.fx - self.alpha * y;
        let td = (x * x + y * y).sqrt();
        if td < AXIS_EPS {
            return Ok(Vector3::z_axis());
        }
        let limit = self.theta_monotonic_limit();
        if td >= self.theta_d(limit) {
            return Err(Reject::DistortionFold);
        }
        let mut t = td.min(limit * 0.999);
        let mut converged = false;
        for _ in 0..UNDISTORT_MAX_ITER {
            let e = self.theta_d(t) - td;
            if e.abs() <= UNDISTORT_TOL * (1.0 + td) {
                converged = true;
                break;
            }
            t = (t - e / self.dtheta_d(t)).clamp(0.0, limit);
        }
        if !converged && (self.theta_d(t) - td).abs() > 1e-12 * (1.0 + td) {
            return Err(Reject::NoConvergence);
        }
        let (s, c) = t.sin_cos();
        Ok(Unit::new_normalize(Vector3::new(s * x / td, s * y / td, c)))
    }

    fn max_theta(&self) -> f64 {
        let lim = self.theta_monotonic_limit();
        match self.fov_deg {
            Some(f) => (f * 0.5).to_radians().min(lim),
            None => lim,
        }
    }
}
