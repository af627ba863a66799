//! The kernel's copies compiled for AVX2 + FMA (x86-64), chosen at run time by the dispatching
//! functions of [`super`] when the CPU has both. Each runs the same inlined body as the baseline
//! copy, so the histograms and visibility are bit-identical to the reference loop.

use super::*;

/// [`accumulate`] compiled for AVX2 + FMA.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn accumulate_avx2(
    pts: &PreparedPoints,
    pose: &PoseF32,
    cam: &FastCamera,
    img: &BinnedImage,
    hist: &mut JointHist,
    scratch: &mut Scratch,
) {
    accumulate_impl::<true, true>(pts, pose, cam, img, hist, scratch);
}

/// [`visible`] compiled for AVX2 + FMA.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn visible_avx2(
    pts: &PreparedPoints,
    pose: &PoseF32,
    cam: &FastCamera,
    img: &BinnedImage,
    invalid: u8,
    out: &mut [bool],
) {
    visible_impl::<true, true>(pts, pose, cam, img, invalid, out);
}

/// [`visible_from_all`] compiled for AVX2 + FMA.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn visible_from_all_avx2(
    pts: &PreparedPoints,
    first: usize,
    poses: &[PoseF32],
    cam: &FastCamera,
    img: &BinnedImage,
    invalid: u8,
    keep: &mut [bool],
) {
    visible_from_all_impl::<true, true>(pts, first, poses, cam, img, invalid, keep);
}

/// [`surely_visible_block`] compiled for AVX2 + FMA.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn surely_visible_block_avx2(
    pts: &PreparedPoints,
    first: usize,
    b: &BoxView<'_>,
    sure: &mut [bool],
) {
    surely_visible_block_impl::<true>(pts, first, b, sure);
}

/// [`project_points`] compiled for AVX2 + FMA.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn project_points_avx2(
    pts: (&[f32], &[f32], &[f32]),
    pose: &PoseF32,
    cam: &FastCamera,
    size: (usize, usize),
    out: (&mut [f32], &mut [f32], &mut [bool]),
) {
    project_points_impl::<true>(pts, pose, cam, size, out);
}

/// Whether this CPU runs the AVX2 + FMA copies of the kernel (the detection is cached by std).
#[cfg(target_arch = "x86_64")]
pub(crate) fn has_avx2_fma() -> bool {
    std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
}
