//! The two lens models as flat parameter vectors, projected generically (plain numbers or jets).
//! The formulas are those of [`crate::camera::Mei`] and [`crate::camera::Equidistant`] (OpenCV
//! `omnidir` / `fisheye`), without their validity checks: the optimiser needs the formula
//! everywhere near the solution; the fitted camera is checked against every observation afterwards.

use super::jet::Real;
use crate::camera::{Camera, Equidistant, Mei};

/// The lens model to calibrate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum LensModel {
    /// Mei unified model (OpenCV `omnidir`): fx, fy, cx, cy, skew, k1, k2, p1, p2, ξ.
    Mei,
    /// Equidistant fisheye (OpenCV `fisheye`, skew fixed at 0): fx, fy, cx, cy, k1..k4.
    Equidistant,
}

/// Names of the Mei parameters, in vector order.
const MEI_NAMES: [&str; 10] = ["fx", "fy", "cx", "cy", "skew", "k1", "k2", "p1", "p2", "xi"];
/// Names of the equidistant parameters, in vector order.
const EQUI_NAMES: [&str; 8] = ["fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"];

impl LensModel {
    /// Parameter names in vector order.
    pub(crate) fn names(self) -> &'static [&'static str] {
        match self {
            LensModel::Mei => &MEI_NAMES,
            LensModel::Equidistant => &EQUI_NAMES,
        }
    }

    /// Number of intrinsic parameters.
    pub(crate) fn n_params(self) -> usize {
        self.names().len()
    }

    /// Distortion-free start: generalised focal `gamma` of the Mei model at ξ = 1 (for the
    /// equidistant model the focal with the same scale near the axis, γ/2), centre `c`.
    pub(crate) fn initial(self, gamma: f64, c: [f64; 2]) -> Vec<f64> {
        match self {
            LensModel::Mei => vec![gamma, gamma, c[0], c[1], 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
            LensModel::Equidistant => {
                let f = gamma / 2.0;
                vec![f, f, c[0], c[1], 0.0, 0.0, 0.0, 0.0]
            }
        }
    }

    /// Project a camera-frame point; `None` where the formula has no value (behind the mirror,
    /// on the axis of symmetry behind the camera).
    #[inline]
    pub(crate) fn project<T: Real>(self, p: &[T], x: [T; 3]) -> Option<[T; 2]> {
        match self {
            LensModel::Mei => {
                let n = (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt();
                if !(n.val() > 0.0) {
                    return None;
                }
                let den = x[2] / n + p[9];
                if !(den.val() > 1e-9) {
                    return None;
                }
                let (xu, yu) = (x[0] / n / den, x[1] / n / den);
                let r2 = xu * xu + yu * yu;
                let radial = p[5] * r2 + p[6] * r2 * r2 + 1.0;
                let (t1, t2) = (p[7], p[8]);
                let xd = xu * radial + t1 * xu * yu * 2.0 + t2 * (r2 + xu * xu * 2.0);
                let yd = yu * radial + t1 * (r2 + yu * yu * 2.0) + t2 * xu * yu * 2.0;
                Some([p[0] * xd + p[4] * yd + p[2], p[1] * yd + p[3]])
            }
            LensModel::Equidistant => {
                let rho = (x[0] * x[0] + x[1] * x[1]).sqrt();
                if !(rho.val() > 1e-12 * x[2].val().abs()) {
                    return if x[2].val() > 0.0 {
                        Some([p[0] * x[0] / x[2] + p[2], p[1] * x[1] / x[2] + p[3]])
                    } else {
                        None
                    };
                }
                let t = rho.atan2(x[2]);
                let t2 = t * t;
                let td = t * (t2 * (t2 * (t2 * (t2 * p[7] + p[6]) + p[5]) + p[4]) + 1.0);
                let s = td / rho;
                Some([p[0] * x[0] * s + p[2], p[1] * x[1] * s + p[3]])
            }
        }
    }

    /// The fitted camera as the crate's model.
    pub(crate) fn camera(self, p: &[f64], width: u32, height: u32) -> Camera {
        match self {
            LensModel::Mei => Camera::Mei(Mei {
                width,
                height,
                fx: p[0],
                fy: p[1],
                cx: p[2],
                cy: p[3],
                skew: p[4],
                k1: p[5],
                k2: p[6],
                p1: p[7],
                p2: p[8],
                xi: p[9],
                fov_deg: None,
            }),
            LensModel::Equidistant => Camera::Equidistant(Equidistant {
                width,
                height,
                fx: p[0],
                fy: p[1],
                cx: p[2],
                cy: p[3],
                alpha: 0.0,
                k1: p[4],
                k2: p[5],
                k3: p[6],
                k4: p[7],
                fov_deg: None,
                cache: Default::default(),
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::CameraModel;
    use nalgebra::Vector3;

    #[test]
    fn generic_projection_equals_the_camera_models() {
        let mei = [
            408.9, 410.5, 630.3, 431.9, -0.63, -0.0083, 0.0118, 0.0228, -0.0042, 1.053,
        ];
        let equi = [300.0, 300.3, 511.0, 509.0, -0.01, 0.001, -2e-4, 2e-5];
        for (model, p) in [
            (LensModel::Mei, &mei[..]),
            (LensModel::Equidistant, &equi[..]),
        ] {
            let cam = model.camera(p, 1280, 1024);
            for x in [
                Vector3::new(0.3, -0.2, 1.0),
                Vector3::new(-2.0, 1.5, 0.4),
                Vector3::new(1.0, 0.5, -0.05),
                Vector3::new(0.0, 0.0, 2.0),
            ] {
                let want = cam.project(&x).unwrap();
                let got = model.project(p, [x.x, x.y, x.z]).unwrap();
                assert!(
                    (got[0] - want.x).abs() < 1e-9 && (got[1] - want.y).abs() < 1e-9,
                    "{model:?} {x:?}: {got:?} vs {want:?}"
                );
            }
        }
    }
}
