//! The kernel's self-test (`infraloc self-test`: the dispatched copy against the plain reference
//! loop, bit for bit, on this CPU) and the instruction-count workload beside it, both on one
//! `5mp`-like Mei scene.

use super::*;
use crate::localize::error::SelfTestError;

/// Which copy of the projection [`accumulate`] runs on this CPU: `neon` (aarch64: the explicit
/// NEON copy of the Mei projection), `avx2+fma` (x86-64 with both, detected at run time) or
/// `baseline`.
pub fn kernel_path() -> &'static str {
    #[cfg(target_arch = "aarch64")]
    return "neon";
    #[cfg(target_arch = "x86_64")]
    if has_avx2_fma() {
        return "avx2+fma";
    }
    #[allow(unreachable_code)]
    "baseline"
}

/// A `5mp`-preset-like Mei camera (2448×2048, the simulator's intrinsics, 185°) for the self-test
/// and the instruction-count workload.
pub(crate) fn test_camera_mei() -> Camera {
    Camera::Mei(crate::camera::Mei {
        width: 2448,
        height: 2048,
        fx: 1196.8,
        fy: 1197.2,
        cx: 1219.8,
        cy: 1022.1,
        skew: 0.0,
        xi: 1.2,
        k1: -0.2696,
        k2: 0.0933,
        p1: -4.0e-5,
        p2: 1.4e-4,
        fov_deg: Some(185.0),
    })
}

/// A 185° equidistant test camera of `size` px, focal `f` px and principal point `c`, with a
/// mild distortion (the sure-visibility tests' second model).
#[cfg(test)]
pub(crate) fn test_camera_equidistant(size: (u32, u32), f: f64, c: (f64, f64)) -> Camera {
    Camera::Equidistant(crate::camera::Equidistant {
        width: size.0,
        height: size.1,
        fx: f,
        fy: f + 0.4,
        cx: c.0,
        cy: c.1,
        alpha: 0.0,
        k1: 0.02,
        k2: -0.004,
        k3: 0.0005,
        k4: 0.0,
        fov_deg: Some(185.0),
        cache: Default::default(),
    })
}

/// The scene of [`self_test`] and [`workload`]: ground points on a 40 m disc around (10, 20) at a
/// 0.25 m spacing (every 7th lifted above the camera, so rays past the 92.5° limit and behind
/// it are exercised), their pre-binned image, and the camera 6 m up.
pub(crate) fn test_scene(cam: &Camera) -> (PreparedPoints, BinnedImage, [f64; 3]) {
    use crate::localize::mi::{bin_lut, Binning};
    let tex = crate::localize::synth::Texture::new(9);
    let mut pts =
        crate::localize::synth::ground_points(&tex, (10.0, 20.0), 40.0, 0.25, 0.0, 3.0, 1);
    for p in pts.iter_mut().step_by(7) {
        p.z = 6.5;
    }
    let (w, h) = (cam.width() as usize, cam.height() as usize);
    let mask = cam.valid_mask();
    let gray: Vec<u8> = (0..w * h).map(|i| ((i * 7919) % 251) as u8).collect();
    let lut = bin_lut(Binning::Uniform, 32, &[0; 256]);
    let origin = test_scene_origin();
    (
        PreparedPoints::new(&pts, origin, &lut),
        BinnedImage::new(w, h, &gray, &mask, &lut, 32),
        origin,
    )
}

/// The origin of [`test_scene`]'s shifted points.
pub(crate) fn test_scene_origin() -> [f64; 3] {
    [10.3, 19.8, 6.0]
}

/// Pose `j` of the self-test and workload: the camera 6 m above (10, 20), yaw, tilt and position
/// varied with `j`.
pub(crate) fn test_pose(j: usize, origin: [f64; 3]) -> PoseF32 {
    PoseF32::new(&test_pose_f64(j), origin)
}

/// [`test_pose`] in f64 (the smooth estimator's self-test).
pub(crate) fn test_pose_f64(j: usize) -> CamFromMap {
    let t = j as f64;
    let c = Point3::new(
        10.0 + 0.37 * (t * 0.7).sin(),
        20.0 - 0.29 * (t * 1.3).cos(),
        6.0 + 0.1 * (t * 0.5).sin(),
    );
    CamFromMap::from_center_ypr(
        &c,
        0.11 * t,
        0.03 * (t * 0.9).sin(),
        -0.04 * (t * 1.1).cos(),
    )
}

/// What [`self_test`] compared.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SelfTest {
    /// [`kernel_path`].
    pub path: &'static str,
    /// Points per pose.
    pub points: usize,
    /// Poses compared.
    pub poses: usize,
}

/// Check, on this CPU, that the dispatched kernel ([`accumulate`], [`visible`],
/// [`visible_from_all`]: NEON on aarch64, AVX2 + FMA where x86-64 has it) gives bit-identical
/// histograms and visibility to the plain reference loop ([`accumulate_reference`]) on a `5mp`
/// Mei camera, `poses` poses. `Err` names the first pose that differs. Run by the unit tests and
/// by `infraloc self-test` (which CI runs on the aarch64 binary under qemu).
pub fn self_test(poses: usize) -> std::result::Result<SelfTest, SelfTestError> {
    let cam = test_camera_mei();
    let (pts, img, origin) = test_scene(&cam);
    let fc = FastCamera::new(&cam, 0);
    let (mut s1, mut s2) = (Scratch::default(), Scratch::default());
    let (mut v1, mut v2) = (vec![false; pts.len()], vec![false; pts.len()]);
    let mut all = vec![true; pts.len()];
    let ps: Vec<PoseF32> = (0..poses).map(|j| test_pose(j, origin)).collect();
    let (mut seen, mut lost) = (0u64, 0u64);
    for (j, p) in ps.iter().enumerate() {
        let (mut a, mut b) = (JointHist::new(32, 32), JointHist::new(32, 32));
        accumulate(&pts, p, &fc, &img, &mut a, &mut s1);
        accumulate_reference(&pts, p, &fc, &img, &mut b, &mut s2);
        if a != b {
            return Err(SelfTestError::Kernel {
                pose: j,
                path: kernel_path(),
                what: "histogram",
            });
        }
        visible(&pts, p, &fc, &img, 32, &mut v1);
        if fused() {
            visible_impl::<false, true>(&pts, p, &fc, &img, 32, &mut v2);
        } else {
            visible_impl::<false, false>(&pts, p, &fc, &img, 32, &mut v2);
        }
        if v1 != v2 {
            return Err(SelfTestError::Kernel {
                pose: j,
                path: kernel_path(),
                what: "visibility",
            });
        }
        all.iter_mut().zip(&v2).for_each(|(k, &v)| *k &= v);
        seen += a.valid_count();
        lost += a.invalid_count();
    }
    let mut got = vec![true; pts.len()];
    visible_from_all(&pts, 0, &ps, &fc, &img, 32, &mut got);
    if got != all {
        return Err(SelfTestError::AllPoses);
    }
    // The scene must exercise both outcomes, or the comparison proves little.
    if seen == 0 || lost == 0 {
        return Err(SelfTestError::Degenerate {
            seen,
            seen_word: "valid",
            lost,
            lost_word: "invalid samples",
        });
    }
    Ok(SelfTest {
        path: kernel_path(),
        points: pts.len(),
        poses,
    })
}

/// The instruction-count workload (docs/benchmarks.md "aarch64"): `poses` evaluations of the
/// self-test's scene, single-threaded, with the dispatched kernel or (`reference`) the plain loop.
/// Returns the number of points and a checksum of the histograms (so nothing is optimised away).
pub fn workload(poses: usize, reference: bool) -> (usize, u64) {
    let cam = test_camera_mei();
    let (pts, img, origin) = test_scene(&cam);
    let fc = FastCamera::new(&cam, 0);
    let mut scratch = Scratch::default();
    let mut sum = 0u64;
    for j in 0..poses {
        let mut h = JointHist::new(32, 32);
        let p = test_pose(j, origin);
        if reference {
            accumulate_reference(&pts, &p, &fc, &img, &mut h, &mut scratch);
        } else {
            accumulate(&pts, &p, &fc, &img, &mut h, &mut scratch);
        }
        sum = sum.wrapping_mul(31).wrapping_add(h.valid_count());
    }
    (pts.len(), sum)
}
