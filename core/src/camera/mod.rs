//! Camera models over *bearings*: pixel → unit ray and ray → pixel (or a reason it cannot be).
//!
//! PnP, MI refinement, rectification and the simulator only ever see [`CameraModel`], so they do not
//! care which lens is fitted. Pixel coordinates follow OpenCV: the centre of the top-left pixel is
//! (0, 0).

mod equidistant;
pub mod error;
pub mod import;
pub mod kitti_rigs;
mod mei;
pub mod rectify;

pub use equidistant::Equidistant;
pub use error::CameraError;
use error::FULL_TURN_DEG;
pub use import::{parse_camera, to_opencv_yaml};
pub use mei::Mei;
pub(crate) use mei::PreparedMei;

use nalgebra::{Point2, Unit, Vector3};
use serde::{Deserialize, Serialize};

/// Why a ray or pixel has no counterpart under the model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum Reject {
    /// The ray lies outside the part of the sphere the model maps one-to-one (behind the mirror).
    #[error("ray outside the model's field of view")]
    OutsideFov,
    /// The distortion polynomial folds over beyond this radius: the mapping is not invertible.
    #[error("beyond the distortion's monotonic range")]
    DistortionFold,
    /// Iterative undistortion did not converge.
    #[error("undistortion did not converge")]
    NoConvergence,
    /// The pixel is outside the sensor.
    #[error("pixel outside the image")]
    OutsideImage,
    /// Zero-length ray or non-finite input.
    #[error("degenerate input")]
    Degenerate,
}

/// Maximum Newton iterations for undistortion; convergence is quadratic, 20 is ample.
pub(crate) const UNDISTORT_MAX_ITER: usize = 30;
/// Undistortion convergence threshold on the normalised-plane residual.
pub(crate) const UNDISTORT_TOL: f64 = 1e-15;

/// A central camera model.
pub trait CameraModel: Send + Sync + std::fmt::Debug {
    /// Image width in pixels.
    fn width(&self) -> u32;
    /// Image height in pixels.
    fn height(&self) -> u32;
    /// Project a camera-frame point (or direction) to a pixel. Pixels outside the sensor are
    /// returned, not rejected: use [`CameraModel::in_image`] for that.
    fn project(&self, p_cam: &Vector3<f64>) -> Result<Point2<f64>, Reject>;
    /// Unit bearing of a pixel.
    fn unproject(&self, px: &Point2<f64>) -> Result<Unit<Vector3<f64>>, Reject>;
    /// Largest angle from the optical axis the lens sees (half the field of view), radians.
    fn max_theta(&self) -> f64;

    /// This camera as the unified (Mei) model, when it is one: a loop over many points behind a
    /// `dyn CameraModel` calls the model through it directly (the same functions, inlined, with
    /// no dynamic calls per point).
    fn as_mei(&self) -> Option<&Mei> {
        None
    }

    /// Whether a pixel lies on the sensor (pixel centres from 0 to size−1, half a pixel margin).
    fn in_image(&self, px: &Point2<f64>) -> bool {
        px.x >= -0.5
            && px.y >= -0.5
            && px.x <= self.width() as f64 - 0.5
            && px.y <= self.height() as f64 - 0.5
    }

    /// Whether a pixel sees the scene: on the sensor, invertible, and inside the image circle.
    fn is_valid_pixel(&self, px: &Point2<f64>) -> bool {
        self.in_image(px)
            && self
                .unproject(px)
                .map(|b| b.z.clamp(-1.0, 1.0).acos() <= self.max_theta())
                .unwrap_or(false)
    }

    /// Project a camera-frame point only if it is seen: inside the field of view and on the sensor.
    fn project_visible(&self, p_cam: &Vector3<f64>) -> Result<Point2<f64>, Reject> {
        self.project_visible_cos(p_cam, self.max_theta().cos())
    }

    /// [`Self::project_visible`] with the field-of-view limit given as its cosine
    /// (`cos_max_theta` = cos [`Self::max_theta`], which some models derive with a few
    /// transcendental calls: a loop over many points computes it once and passes it here, and
    /// comparing the ray's cosine with it spares an `acos` per point).
    fn project_visible_cos(
        &self,
        p_cam: &Vector3<f64>,
        cos_max_theta: f64,
    ) -> Result<Point2<f64>, Reject> {
        let n = p_cam.norm();
        if !(n > 0.0) {
            return Err(Reject::Degenerate);
        }
        if p_cam.z / n < cos_max_theta {
            return Err(Reject::OutsideFov);
        }
        let px = self.project(p_cam)?;
        if self.in_image(&px) {
            Ok(px)
        } else {
            Err(Reject::OutsideImage)
        }
    }

    /// Validity mask (255 = valid) of the image circle, row-major `width × height`.
    ///
    /// Every pixel is an unprojection (≈ 0.5 s of CPU for 5 MP), so the validity is sampled on a
    /// lattice of `MASK_BLOCK`-pixel blocks first: a block whose lattice corners, and those of
    /// its eight neighbours, all agree is filled with that value; every other block (the image
    /// circle's rim, the sensor's edge) is evaluated pixel by pixel. That equals the per-pixel
    /// mask when the invalid set has no island or sliver narrower than a block between lattice
    /// points (nor a chord that short where the circle grazes the sensor's edge) — true of the
    /// image circle of every model here (a disc, a lens's fold beyond it);
    /// [`CameraModel::valid_mask_exact`] is the per-pixel reference, and what sensors with a side
    /// under `MASK_MIN_SIDE` get. Rows in parallel (rayon).
    fn valid_mask(&self) -> Vec<u8> {
        use rayon::prelude::*;
        let (w, h) = (self.width() as usize, self.height() as usize);
        if w.min(h) < MASK_MIN_SIDE {
            // Too narrow for the lattice to resolve its image circle.
            return self.valid_mask_exact();
        }
        let lattice = |n: usize| -> Vec<usize> {
            let mut v: Vec<usize> = (0..n).step_by(MASK_BLOCK).collect();
            if v.last() != Some(&(n - 1)) {
                v.push(n - 1);
            }
            v
        };
        let (xs, ys) = (lattice(w), lattice(h));
        let corner: Vec<Vec<bool>> = ys
            .par_iter()
            .map(|&v| {
                xs.iter()
                    .map(|&u| self.is_valid_pixel(&Point2::new(u as f64, v as f64)))
                    .collect()
            })
            .collect();
        // Block (i, j) spans columns xs[i]..xs[i+1] and rows ys[j]..ys[j+1] (the last block of a
        // row or column includes its end). `Some(value)` when it may be filled.
        let (bw, bh) = (xs.len() - 1, ys.len() - 1);
        let uniform = |i: usize, j: usize| -> Option<bool> {
            let c = corner[j][i];
            let (i0, i1) = (i.saturating_sub(1), (i + 2).min(bw));
            let (j0, j1) = (j.saturating_sub(1), (j + 2).min(bh));
            (j0..=j1)
                .all(|jj| (i0..=i1).all(|ii| corner[jj][ii] == c))
                .then_some(c)
        };
        // The sides are ≥ MASK_MIN_SIDE, so there are several blocks each way.
        let fill: Vec<Vec<Option<bool>>> = (0..bh)
            .map(|j| (0..bw).map(|i| uniform(i, j)).collect())
            .collect();
        // Lattice points are multiples of the block size (plus the last pixel, which closes the
        // last block).
        let block_of = |x: usize, blocks: usize| (x / MASK_BLOCK).min(blocks - 1);
        let mut m = vec![0u8; w * h];
        m.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
            let j = block_of(v, bh);
            for (u, px) in row.iter_mut().enumerate() {
                let valid = match fill[j][block_of(u, bw)] {
                    Some(c) => c,
                    None => self.is_valid_pixel(&Point2::new(u as f64, v as f64)),
                };
                if valid {
                    *px = 255;
                }
            }
        });
        m
    }

    /// [`CameraModel::valid_mask`] evaluated at every pixel (the reference it is tested against).
    fn valid_mask_exact(&self) -> Vec<u8> {
        use rayon::prelude::*;
        let (w, h) = (self.width() as usize, self.height() as usize);
        let mut m = vec![0u8; w * h];
        m.par_chunks_mut(w.max(1)).enumerate().for_each(|(v, row)| {
            for (u, px) in row.iter_mut().enumerate() {
                if self.is_valid_pixel(&Point2::new(u as f64, v as f64)) {
                    *px = 255;
                }
            }
        });
        m
    }
}

/// Block size of [`CameraModel::valid_mask`]'s lattice, pixels.
pub(crate) const MASK_BLOCK: usize = 8;
/// Sensors with a side shorter than this (pixels) get the per-pixel mask.
pub(crate) const MASK_MIN_SIDE: usize = 8 * MASK_BLOCK;

/// Any supported camera, as loaded from an intrinsics file. Serialises as the native TOML table
/// (`model = "mei" | "equidistant"`, then the parameters).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "kebab-case")]
pub enum Camera {
    /// Mei / unified omnidirectional model (OpenCV `cv::omnidir`).
    Mei(Mei),
    /// Equidistant fisheye (OpenCV `cv::fisheye`).
    Equidistant(Equidistant),
}

impl Camera {
    /// The model as a trait object.
    pub fn model(&self) -> &dyn CameraModel {
        match self {
            Camera::Mei(m) => m,
            Camera::Equidistant(m) => m,
        }
    }

    /// Check the parameters are usable: positive size and focal lengths, finite coefficients,
    /// ξ ≥ 0, field of view in (0°, 360°]. The message names the offending parameter.
    pub fn validate(&self) -> Result<(), CameraError> {
        let (w, h, named): (u32, u32, Vec<(&str, f64)>) = match self {
            Camera::Mei(m) => (
                m.width,
                m.height,
                vec![
                    ("fx", m.fx),
                    ("fy", m.fy),
                    ("cx", m.cx),
                    ("cy", m.cy),
                    ("skew", m.skew),
                    ("xi", m.xi),
                    ("k1", m.k1),
                    ("k2", m.k2),
                    ("p1", m.p1),
                    ("p2", m.p2),
                ],
            ),
            Camera::Equidistant(e) => (
                e.width,
                e.height,
                vec![
                    ("fx", e.fx),
                    ("fy", e.fy),
                    ("cx", e.cx),
                    ("cy", e.cy),
                    ("alpha", e.alpha),
                    ("k1", e.k1),
                    ("k2", e.k2),
                    ("k3", e.k3),
                    ("k4", e.k4),
                ],
            ),
        };
        if w == 0 || h == 0 {
            return Err(CameraError::EmptySize {
                width: w,
                height: h,
            });
        }
        for (name, v) in &named {
            if !v.is_finite() {
                return Err(CameraError::NotFinite { name, value: *v });
            }
            if matches!(*name, "fx" | "fy") && !(*v > 0.0) {
                return Err(CameraError::Focal { name, value: *v });
            }
            if *name == "xi" && *v < 0.0 {
                return Err(CameraError::NegativeXi { value: *v });
            }
        }
        let fov = match self {
            Camera::Mei(m) => m.fov_deg,
            Camera::Equidistant(e) => e.fov_deg,
        };
        if let Some(f) = fov {
            if !(f > 0.0 && f <= FULL_TURN_DEG) {
                return Err(CameraError::FieldOfView { value: f });
            }
        }
        Ok(())
    }
}

impl CameraModel for Camera {
    fn width(&self) -> u32 {
        self.model().width()
    }
    fn height(&self) -> u32 {
        self.model().height()
    }
    fn project(&self, p: &Vector3<f64>) -> Result<Point2<f64>, Reject> {
        self.model().project(p)
    }
    fn unproject(&self, px: &Point2<f64>) -> Result<Unit<Vector3<f64>>, Reject> {
        self.model().unproject(px)
    }
    fn max_theta(&self) -> f64 {
        self.model().max_theta()
    }
    fn as_mei(&self) -> Option<&Mei> {
        self.model().as_mei()
    }
}

/// Solve the 2×2 linear system `J·d = r` (row-major J); `None` if singular.
#[inline]
pub(crate) fn solve2(j: [f64; 4], r: [f64; 2]) -> Option<[f64; 2]> {
    let det = j[0] * j[3] - j[1] * j[2];
    if det.abs() < 1e-300 || !det.is_finite() {
        return None;
    }
    Some([
        (j[3] * r[0] - j[1] * r[1]) / det,
        (j[0] * r[1] - j[2] * r[0]) / det,
    ])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn kitti() -> Mei {
        Mei {
            width: 1400,
            height: 1400,
            fx: 1336.32,
            fy: 1335.79,
            cx: 716.94,
            cy: 705.76,
            skew: 0.0,
            xi: 2.2134,
            k1: 0.0168,
            k2: 1.6549,
            p1: 4.22e-4,
            p2: 4.25e-4,
            fov_deg: None,
        }
    }

    fn check_round_trip(cam: &dyn CameraModel, step: usize) -> usize {
        let mut n = 0;
        for v in (0..cam.height()).step_by(step) {
            for u in (0..cam.width()).step_by(step) {
                let px = Point2::new(u as f64 + 0.25, v as f64 + 0.75);
                if let Ok(b) = cam.unproject(&px) {
                    let back = cam.project(&b).expect("unprojected ray must project");
                    assert!((back - px).norm() < 1e-6, "{px:?} -> {back:?}");
                    n += 1;
                }
            }
        }
        n
    }

    #[test]
    fn block_valid_mask_equals_the_per_pixel_mask() {
        let fisheye = |w: u32, h: u32, fov: Option<f64>| Mei {
            width: w,
            height: h,
            fx: 0.29 * w as f64,
            fy: 0.29 * w as f64,
            cx: w as f64 / 2.0 + 3.3,
            cy: h as f64 / 2.0 - 2.1,
            skew: 0.0,
            xi: 1.2,
            k1: -0.27,
            k2: 0.096,
            p1: -1.6e-4,
            p2: -1.2e-4,
            fov_deg: fov,
        };
        let cams: Vec<Box<dyn CameraModel>> = vec![
            // The image circle inside the sensor, cut by its edges, or absent; odd sizes, so the
            // lattice's last block is short; degenerate 1-pixel sensors.
            Box::new(fisheye(612, 512, Some(185.0))),
            Box::new(fisheye(301, 203, Some(120.0))),
            Box::new(fisheye(257, 257, None)),
            Box::new(kitti()),
            // Just above the lattice's minimum side, with a 1-px last block.
            Box::new(fisheye(65, 73, Some(185.0))),
            Box::new(fisheye(64, 200, Some(150.0))),
            Box::new(Equidistant {
                width: 333,
                height: 250,
                fx: 90.0,
                fy: 90.0,
                cx: 170.0,
                cy: 120.0,
                alpha: 0.0,
                k1: 0.01,
                k2: -0.003,
                k3: 0.0,
                k4: 0.0,
                fov_deg: Some(190.0),
                cache: Default::default(),
            }),
        ];
        for (i, cam) in cams.iter().enumerate() {
            let (m, e) = (cam.valid_mask(), cam.valid_mask_exact());
            assert_eq!(m.len(), (cam.width() * cam.height()) as usize);
            let differ = m.iter().zip(&e).filter(|(a, b)| a != b).count();
            assert_eq!(differ, 0, "camera {i}: {differ} pixels differ");
        }
        // The lattice matters: these sensors have both valid and invalid pixels.
        for i in [0, 1, 4, 5] {
            let m = cams[i].valid_mask();
            assert!(m.contains(&0) && m.contains(&255), "camera {i}");
        }
        // Sensors under the lattice's minimum side take the per-pixel path.
        let tiny = fisheye(17, 1, Some(185.0));
        assert_eq!(tiny.valid_mask(), tiny.valid_mask_exact());
    }

    #[test]
    fn mei_round_trip_kitti_xi_above_2() {
        let n = check_round_trip(&kitti(), 37);
        assert!(n > 1000, "only {n} pixels valid");
    }

    #[test]
    fn mei_round_trip_beyond_90_degrees() {
        // ξ < 1 omnidir lens: a ray at θ = 100° must map and come back.
        let cam = Mei {
            width: 1280,
            height: 960,
            fx: 700.0,
            fy: 702.0,
            cx: 640.0,
            cy: 480.0,
            skew: 0.5,
            xi: 0.9,
            k1: -0.2,
            k2: 0.05,
            p1: 1e-4,
            p2: -2e-4,
            fov_deg: None,
        };
        let th = 100f64.to_radians();
        let ray = Vector3::new(th.sin() * 0.6, th.sin() * 0.8, th.cos());
        let px = cam.project(&ray).unwrap();
        let b = cam.unproject(&px).unwrap();
        assert!((b.into_inner() - ray).norm() < 1e-9);
        check_round_trip(&cam, 41);
    }

    #[test]
    fn equidistant_round_trip_beyond_90_degrees() {
        let cam = Equidistant {
            width: 2448,
            height: 2048,
            fx: 780.0,
            fy: 780.0,
            cx: 1224.0,
            cy: 1024.0,
            alpha: 0.0,
            k1: 0.01,
            k2: -0.002,
            k3: 0.0005,
            k4: -0.0001,
            fov_deg: Some(185.0),
            cache: Default::default(),
        };
        for deg in [0.0, 30.0, 89.0, 91.0, 92.5] {
            let th = f64::to_radians(deg);
            let ray = Vector3::new(th.sin() * 0.8, -th.sin() * 0.6, th.cos());
            let px = cam.project(&ray).unwrap();
            let b = cam.unproject(&px).unwrap();
            assert!((b.into_inner() - ray).norm() < 1e-9, "θ={deg}");
        }
        check_round_trip(&cam, 53);
    }

    #[test]
    fn mei_rejects_behind_mirror() {
        let cam = kitti();
        // ξ > 1: rays with z_s < −1/ξ fold back and must be rejected.
        assert_eq!(
            cam.project(&Vector3::new(0.1, 0.0, -1.0)),
            Err(Reject::OutsideFov)
        );
    }

    #[test]
    fn mei_max_theta_stops_at_the_distortion_fold() {
        // ξ = 0, k1 = −0.3: r(1 + k1 r²) peaks at r² = 1/(3·0.3), i.e. θ = atan(1.0541) = 46.49°.
        let mut cam = Mei::pinhole(1000, 1000, 400.0, 400.0, 500.0, 500.0);
        cam.k1 = -0.3;
        let fold = (1.0f64 / 0.9).sqrt().atan();
        assert!(
            (cam.max_theta() - fold).abs() < 1e-12,
            "{}",
            cam.max_theta()
        );
        let ray = |deg: f64| Vector3::new(deg.to_radians().sin(), 0.0, deg.to_radians().cos());
        assert!(cam.project(&ray(46.0)).is_ok());
        assert_eq!(cam.project(&ray(47.0)), Err(Reject::DistortionFold));
        // The fold of KITTI-360's lens (k1, k2 > 0) never happens: the mirror limit rules.
        let k = kitti();
        assert!((k.max_theta() - (-1.0 / k.xi).acos()).abs() < 1e-15);
    }

    #[test]
    fn equidistant_near_backward_axis_is_not_the_forward_axis() {
        let cam = Equidistant {
            width: 1000,
            height: 1000,
            fx: 300.0,
            fy: 300.0,
            cx: 500.0,
            cy: 500.0,
            alpha: 0.0,
            k1: 0.0,
            k2: 0.0,
            k3: 0.0,
            k4: 0.0,
            fov_deg: None,
            cache: Default::default(),
        };
        // θ = π − 1e-14 at azimuth 0: the pixel lies at radius fx·θ, not at the centre.
        let px = cam.project(&Vector3::new(1e-14, 0.0, -1.0)).unwrap();
        assert!((px.x - (500.0 + 300.0 * (std::f64::consts::PI - 1e-14))).abs() < 1e-9);
        assert!(cam.project(&Vector3::new(0.0, 0.0, -1.0)).is_err());
    }

    #[test]
    fn pinhole_is_mei_with_zero_xi() {
        let cam = Mei::pinhole(640, 480, 500.0, 500.0, 320.0, 240.0);
        let px = cam.project(&Vector3::new(1.0, -0.5, 2.0)).unwrap();
        assert!((px.x - 570.0).abs() < 1e-12 && (px.y - 115.0).abs() < 1e-12);
        assert!(cam.project(&Vector3::new(0.0, 0.0, -1.0)).is_err());
    }
}
