//! Mei / unified omnidirectional model, bit-for-bit the formula of `cv::omnidir::projectPoints`.

use super::{solve2, CameraModel, Reject, UNDISTORT_MAX_ITER, UNDISTORT_TOL};
use nalgebra::{Point2, Unit, Vector3};
use serde::{Deserialize, Serialize};

/// Mei unified model: unit sphere → shift by ξ → plane → radtan distortion → affine with skew.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", deny_unknown_fields)]
pub struct Mei {
    /// Image width (px).
    pub width: u32,
    /// Image height (px).
    pub height: u32,
    /// Generalised focal length γ1 (px).
    pub fx: f64,
    /// Generalised focal length γ2 (px).
    pub fy: f64,
    /// Principal point u0 (px).
    pub cx: f64,
    /// Principal point v0 (px).
    pub cy: f64,
    /// Skew `s` = `K[0][1]` (px), as in OpenCV omnidir.
    #[serde(default)]
    pub skew: f64,
    /// Mirror parameter ξ (0 = pinhole).
    pub xi: f64,
    /// Radial k1.
    #[serde(default)]
    pub k1: f64,
    /// Radial k2.
    #[serde(default)]
    pub k2: f64,
    /// Tangential p1.
    #[serde(default)]
    pub p1: f64,
    /// Tangential p2.
    #[serde(default)]
    pub p2: f64,
    /// Lens field of view in degrees (full angle), if known; limits the valid image circle.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fov_deg: Option<f64>,
}

impl Mei {
    /// An ideal pinhole camera (ξ = 0, no distortion).
    pub fn pinhole(width: u32, height: u32, fx: f64, fy: f64, cx: f64, cy: f64) -> Self {
        Mei {
            width,
            height,
            fx,
            fy,
            cx,
            cy,
            skew: 0.0,
            xi: 0.0,
            k1: 0.0,
            k2: 0.0,
            p1: 0.0,
            p2: 0.0,
            fov_deg: None,
        }
    }

    /// Lowest sphere z the model maps one-to-one: the denominator `z+ξ` must stay positive and, for
    /// ξ > 1, the ray must be in front of the tangent cone (z > −1/ξ).
    fn min_sphere_z(&self) -> f64 {
        if self.xi <= 1.0 {
            -self.xi
        } else {
            -1.0 / self.xi
        }
    }

    /// Largest undistorted radius r² where the radial polynomial is still increasing:
    /// d/dr[r(1+k1 r²+k2 r⁴)] = 1 + 3k1 s + 5k2 s² > 0 with s = r².
    fn max_r2_monotonic(&self) -> f64 {
        smallest_positive_root(5.0 * self.k2, 3.0 * self.k1, 1.0).unwrap_or(f64::INFINITY)
    }

    /// Angle from the axis at which the radial distortion folds over (π if it never does inside
    /// the mirror's range): the ray whose undistorted radius is `sqrt(max_r2_monotonic)`.
    fn fold_theta(&self) -> f64 {
        let r2 = self.max_r2_monotonic();
        if !r2.is_finite() {
            return std::f64::consts::PI;
        }
        let disc = 1.0 + (1.0 - self.xi * self.xi) * r2;
        if disc < 0.0 {
            // Beyond the tangent cone (ξ > 1): the fold is never reached by a real ray.
            return std::f64::consts::PI;
        }
        let lambda = (self.xi + disc.sqrt()) / (r2 + 1.0);
        (lambda - self.xi).clamp(-1.0, 1.0).acos()
    }

    /// Apply the radtan distortion to a normalised point.
    #[inline]
    fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let r2 = x * x + y * y;
        let r4 = r2 * r2;
        let radial = 1.0 + self.k1 * r2 + self.k2 * r4;
        // Same expression order as OpenCV so results agree to the last bits.
        let xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y;
        (xd, yd)
    }

    /// Invert [`Mei::distort`] by Newton's method with the analytic Jacobian.
    fn undistort(&self, xd: f64, yd: f64) -> Result<(f64, f64), Reject> {
        let (mut x, mut y) = (xd, yd);
        let scale = 1.0 + xd.abs() + yd.abs();
        for _ in 0..UNDISTORT_MAX_ITER {
            let (fx, fy) = self.distort(x, y);
            let (ex, ey) = (fx - xd, fy - yd);
            if !(ex.is_finite() && ey.is_finite()) {
                return Err(Reject::NoConvergence);
            }
            if ex.abs().max(ey.abs()) <= UNDISTORT_TOL * scale {
                return Ok((x, y));
            }
            let r2 = x * x + y * y;
            let radial = 1.0 + self.k1 * r2 + self.k2 * r2 * r2;
            let dradial = 2.0 * self.k1 + 4.0 * self.k2 * r2; // d(radial)/d(r2) · 2
            let j00 = radial + x * dradial * x + 2.0 * self.p1 * y + 6.0 * self.p2 * x;
            let j01 = x * dradial * y + 2.0 * self.p1 * x + 2.0 * self.p2 * y;
            let j10 = y * dradial * x + 2.0 * self.p1 * x + 2.0 * self.p2 * y;
            let j11 = radial + y * dradial * y + 6.0 * self.p1 * y + 2.0 * self.p2 * x;
            let d = solve2([j00, j01, j10, j11], [ex, ey]).ok_or(Reject::NoConvergence)?;
            x -= d[0];
            y -= d[1];
        }
        // Accept the last iterate only if it is as good as the tolerance allows in practice.
        let (fx, fy) = self.distort(x, y);
        if (fx - xd).abs().max((fy - yd).abs()) <= 1e-12 * scale {
            Ok((x, y))
        } else {
            Err(Reject::NoConvergence)
        }
    }
}

/// Smallest positive root of a·s² + b·s + c (c > 0), if any.
pub(crate) fn smallest_positive_root(a: f64, b: f64, c: f64) -> Option<f64> {
    if a.abs() < 1e-300 {
        return if b < 0.0 { Some(-c / b) } else { None };
    }
    let disc = b * b - 4.0 * a * c;
    if disc < 0.0 {
        return None;
    }
    let sq = disc.sqrt();
    let mut roots = [(-b - sq) / (2.0 * a), (-b + sq) / (2.0 * a)];
    roots.sort_by(f64::total_cmp);
    roots.into_iter().find(|r| *r > 0.0)
}

impl Mei {
    /// [`CameraModel::project`] with the model's two limits given: the lowest sphere z and
    /// (asked only for a ray in front of it) the largest undistorted r².
    #[inline(always)]
    fn project_with(
        &self,
        p: &Vector3<f64>,
        min_sphere_z: f64,
        max_r2: impl FnOnce() -> f64,
    ) -> Result<Point2<f64>, Reject> {
        let n = p.norm();
        if !(n > 0.0 && n.is_finite()) {
            return Err(Reject::Degenerate);
        }
        let s = p / n;
        if s.z <= min_sphere_z {
            return Err(Reject::OutsideFov);
        }
        let denom = s.z + self.xi;
        let (xu, yu) = (s.x / denom, s.y / denom);
        if xu * xu + yu * yu >= max_r2() {
            return Err(Reject::DistortionFold);
        }
        let (xd, yd) = self.distort(xu, yu);
        Ok(Point2::new(
            self.fx * xd + self.skew * yd + self.cx,
            self.fy * yd + self.cy,
        ))
    }
}

/// A [`Mei`] camera whose projection limits (lowest sphere z, largest undistorted r², a square
/// root and two divisions per call otherwise) are computed once: the same model and the same
/// numbers, for loops that project many points in f64 (the initializer's patches).
#[derive(Debug, Clone, Copy)]
pub(crate) struct PreparedMei<'a> {
    mei: &'a Mei,
    min_sphere_z: f64,
    max_r2: f64,
    max_theta: f64,
}

impl<'a> PreparedMei<'a> {
    /// The limits of `mei`.
    pub(crate) fn new(mei: &'a Mei) -> Self {
        PreparedMei {
            mei,
            min_sphere_z: mei.min_sphere_z(),
            max_r2: mei.max_r2_monotonic(),
            max_theta: mei.max_theta(),
        }
    }
}

impl CameraModel for PreparedMei<'_> {
    fn as_mei(&self) -> Option<&Mei> {
        Some(self.mei)
    }
    fn width(&self) -> u32 {
        self.mei.width
    }
    fn height(&self) -> u32 {
        self.mei.height
    }
    #[inline]
    fn project(&self, p: &Vector3<f64>) -> Result<Point2<f64>, Reject> {
        self.mei.project_with(p, self.min_sphere_z, || self.max_r2)
    }
    fn unproject(&self, px: &Point2<f64>) -> Result<Unit<Vector3<f64>>, Reject> {
        self.mei.unproject(px)
    }
    fn max_theta(&self) -> f64 {
        self.max_theta
    }
}

impl CameraModel for Mei {
    fn as_mei(&self) -> Option<&Mei> {
        Some(self)
    }
    fn width(&self) -> u32 {
        self.width
    }
    fn height(&self) -> u32 {
        self.height
    }

    fn project(&self, p: &Vector3<f64>) -> Result<Point2<f64>, Reject> {
        self.project_with(p, self.min_sphere_z(), || self.max_r2_monotonic())
    }

    fn unproject(&self, px: &Point2<f64>) -> Result<Unit<Vector3<f64>>, Reject> {
        if !(px.x.is_finite() && px.y.is_finite()) {
            return Err(Reject::Degenerate);
        }
        let yd = (px.y - self.cy) / self.fy;
        let xd = (px.x - self.cx - self.skew * yd) / self.fx;
        let (x, y) = self.undistort(xd, yd)?;
        let r2 = x * x + y * y;
        if r2 >= self.max_r2_monotonic() {
            return Err(Reject::DistortionFold);
        }
        // Lift to the sphere: Xs = λ(x, y, 1) − (0, 0, ξ) with |Xs| = 1.
        let disc = 1.0 + (1.0 - self.xi * self.xi) * r2;
        if disc < 0.0 {
            return Err(Reject::OutsideFov);
        }
        let lambda = (self.xi + disc.sqrt()) / (r2 + 1.0);
        let v = Vector3::new(lambda * x, lambda * y, lambda - self.xi);
        if v.z / v.norm() <= self.min_sphere_z() {
            return Err(Reject::OutsideFov);
        }
        Ok(Unit::new_normalize(v))
    }

    fn max_theta(&self) -> f64 {
        let model = self.min_sphere_z().acos().min(self.fold_theta());
        match self.fov_deg {
            Some(f) => (f * 0.5).to_radians().min(model),
            None => model,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeSet;

    /// The prepared model gives every ray the model's own answer, bit for bit: the pixel, or the
    /// same rejection (behind the mirror, past the distortion's fold, degenerate, off the sensor),
    /// over the whole sphere, for ξ below, at and above 1 and for a radial polynomial that folds.
    #[test]
    fn prepared_mei_projects_exactly_as_the_model() {
        let mut outcomes = BTreeSet::new();
        for (xi, k1, k2) in [
            (1.2, -0.27, 0.09),
            (0.8, -0.4, 0.01),
            (2.0, 0.1, -0.05),
            (0.0, 0.0, 0.0),
        ] {
            let m = Mei {
                width: 640,
                height: 512,
                fx: 300.0,
                fy: 300.5,
                cx: 321.0,
                cy: 255.0,
                skew: 0.3,
                xi,
                k1,
                k2,
                p1: -4.0e-5,
                p2: 1.4e-4,
                fov_deg: Some(185.0),
            };
            let pm = PreparedMei::new(&m);
            assert_eq!(pm.max_theta(), m.max_theta());
            assert_eq!((pm.width(), pm.height()), (m.width, m.height));
            let cos_max = m.max_theta().cos();
            let mut rays = vec![
                Vector3::zeros(),
                Vector3::new(f64::NAN, 0.0, 1.0),
                Vector3::new(0.0, f64::INFINITY, 1.0),
            ];
            for i in 0..=360 {
                for j in 0..24 {
                    let (t, f) = (
                        (i as f64 * 0.5).to_radians(),
                        (j as f64 * 15.0).to_radians(),
                    );
                    rays.push(3.7 * Vector3::new(t.sin() * f.cos(), t.sin() * f.sin(), t.cos()));
                }
            }
            for v in &rays {
                let (a, b) = (pm.project(v), m.project(v));
                assert_eq!(
                    a.map(|p| (p.x.to_bits(), p.y.to_bits())),
                    b.map(|p| (p.x.to_bits(), p.y.to_bits())),
                    "ξ {xi}, ray {v:?}"
                );
                let (a, b) = (
                    pm.project_visible_cos(v, cos_max),
                    m.project_visible_cos(v, cos_max),
                );
                assert_eq!(
                    a.map(|p| (p.x.to_bits(), p.y.to_bits())),
                    b.map(|p| (p.x.to_bits(), p.y.to_bits())),
                    "ξ {xi}, ray {v:?}"
                );
                outcomes.insert(format!("{:?}", b.map(|_| ())));
                outcomes.insert(format!("{:?}", m.project(v).map(|_| ())));
            }
        }
        // Every branch of the projection was compared, not only the pixels.
        for o in [
            "Ok(())",
            "Err(OutsideFov)",
            "Err(DistortionFold)",
            "Err(Degenerate)",
        ] {
            assert!(outcomes.contains(o), "{o} never reached: {outcomes:?}");
        }
    }
}
