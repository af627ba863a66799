//! The explicit NEON copy of the Mei projection (aarch64), bit-identical to the scalar loop of
//! [`super`].

use super::*;

/// [`project_chunk_mei`] with explicit NEON intrinsics, four points per step (aarch64).
///
/// Why by hand: it keeps the loop's constants in registers where the compiler's vectorisation of
/// the plain loop reloads some of them every iteration (fewer instructions per point,
/// docs/benchmarks.md "aarch64"). It must stay bit-identical to the scalar loop, so every lane
/// performs the scalar loop's IEEE operations in the same order and association: `vfmaq`
/// (`_laneq`) exactly where the scalar loop has a `mul_add`, `vmulq`/`vaddq` where it multiplies
/// or adds alone, a correctly
/// rounded `vsqrtq` and `vdivq` (no reciprocal estimates), the truncating `vcvtq_s32_f32` (what
/// the in-range `to_int_unchecked` of [`pixel_index`] is), wrapping u32 index arithmetic as in
/// the scalar code, and `vbslq` for the scalar `if`. Lanes past the last multiple of four go through
/// the scalar loop.
#[cfg(target_arch = "aarch64")]
#[inline(always)]
pub(super) fn project_chunk_mei_neon(
    xs: &[f32],
    ys: &[f32],
    zs: &[f32],
    p: &PoseF32,
    m: MeiConsts,
    t: Raster,
    out: &mut [u32],
) {
    let MeiConsts {
        k,
        xi,
        d,
        zmin,
        r2max,
    } = m;
    let Raster { w, h, sentinel } = t;
    use core::arch::aarch64::*;
    let n_all = out.len().min(xs.len()).min(ys.len()).min(zs.len());
    let body = n_all - n_all % 4;
    let r = p.r;
    let (wf, hf) = (w.min(MAX_SIDE) as f32, h.min(MAX_SIDE) as f32);
    // The scalar loop's `2.0 * d[2]`, `2.0 * d[3]`, `k[3] + 0.5` and `k[4] + 0.5` depend on
    // constants only, so computing them once here gives the same values.
    let (d2x2, d3x2) = (2.0 * d[2], 2.0 * d[3]);
    let (k3h, k4h) = (k[3] + 0.5, k[4] + 0.5);
    // The multipliers packed four to a register and used by lane (`fmla` by element, the same
    // single rounding as a plain `fmla`): one broadcast register per constant would need more than
    // NEON's 32, and the compiler spilled and shuffled them inside the loop (docs/benchmarks.md
    // "aarch64"). Addends and comparison bounds stay broadcast: `fadd` and `fcm*` have no
    // by-element form.
    let (m0, m1, m2, m3, m4) = (
        [r[0], r[1], r[2], r[3]],
        [r[4], r[5], r[6], r[7]],
        [r[8], xi, d[1], 0.0],
        [d2x2, d[2], d[3], d3x2],
        [k[0], k[1], k[2], zmin],
    );
    // black_box hides the lanes' values from the optimiser, which otherwise sees through the
    // packing, turns every by-lane multiply back into a broadcast of its scalar, and spills again.
    let (m0, m1, m2, m3, m4) = core::hint::black_box((m0, m1, m2, m3, m4));
    // SAFETY: NEON is part of the aarch64-unknown-linux-gnu baseline, so the intrinsics run on every
    // CPU this code is compiled for; each load reads four f32 of a local [f32; 4].
    let (m0, m1, m2, m3, m4) = unsafe {
        (
            vld1q_f32(m0.as_ptr()),
            vld1q_f32(m1.as_ptr()),
            vld1q_f32(m2.as_ptr()),
            vld1q_f32(m3.as_ptr()),
            vld1q_f32(m4.as_ptr()),
        )
    };
    let mut i = 0;
    while i < body {
        // SAFETY: NEON is baseline on this target (above). The loads read xs/ys/zs[i..i + 4] and
        // the store writes out[i..i + 4]: in bounds because i + 4 <= body <= each slice's length.
        unsafe {
            let v = |a: f32| vdupq_n_f32(a);
            let (x, y, z) = (
                vld1q_f32(xs.as_ptr().add(i)),
                vld1q_f32(ys.as_ptr().add(i)),
                vld1q_f32(zs.as_ptr().add(i)),
            );
            // `vfmaq(a, b, c)` is a + b·c rounded once: the scalar `b.mul_add(c, a)` (the product
            // commutes), nested as in the scalar expressions.
            // r0·x + (r1·y + (r2·z + t))
            let cx = vfmaq_laneq_f32::<0>(
                vfmaq_laneq_f32::<1>(vfmaq_laneq_f32::<2>(v(p.t[0]), z, m0), y, m0),
                x,
                m0,
            );
            let cy = vfmaq_laneq_f32::<3>(
                vfmaq_laneq_f32::<0>(vfmaq_laneq_f32::<1>(v(p.t[1]), z, m1), y, m1),
                x,
                m0,
            );
            let cz = vfmaq_laneq_f32::<2>(
                vfmaq_laneq_f32::<3>(vfmaq_laneq_f32::<0>(v(p.t[2]), z, m2), y, m1),
                x,
                m1,
            );
            let n = vsqrtq_f32(vfmaq_f32(vfmaq_f32(vmulq_f32(cz, cz), cy, cy), cx, cx));
            // 1 / (cz + ξ·n): a true division, never the reciprocal estimate.
            let f = vdivq_f32(v(1.0), vfmaq_laneq_f32::<1>(cz, n, m2));
            let (xu, yu) = (vmulq_f32(cx, f), vmulq_f32(cy, f));
            let (xx, yy, xy) = (vmulq_f32(xu, xu), vmulq_f32(yu, yu), vmulq_f32(xu, yu));
            let r2 = vaddq_f32(xx, yy);
            // (k1 + k2·r2)·r2 + 1
            let radial = vfmaq_f32(v(1.0), vfmaq_laneq_f32::<2>(v(d[0]), r2, m2), r2);
            let two = v(2.0);
            // xu·radial + (2·p1·xy + p2·(r2 + 2·xx))
            let xd = vfmaq_f32(
                vfmaq_laneq_f32::<0>(vmulq_laneq_f32::<2>(vfmaq_f32(r2, two, xx), m3), xy, m3),
                xu,
                radial,
            );
            // yu·radial + (2·p2·xy + p1·(r2 + 2·yy))
            let yd = vfmaq_f32(
                vfmaq_laneq_f32::<3>(vmulq_laneq_f32::<1>(vfmaq_f32(r2, two, yy), m3), xy, m3),
                yu,
                radial,
            );
            // k0·xd + (k2·yd + (k3 + ½)) and k1·yd + (k4 + ½)
            let u = vfmaq_laneq_f32::<0>(vfmaq_laneq_f32::<2>(v(k3h), yd, m4), xd, m4);
            let vv = vfmaq_laneq_f32::<1>(v(k4h), yd, m4);
            // IEEE comparisons are false for NaN, as the scalar `>`, `<`, `>=` are.
            let zero = v(0.0);
            let ok = vandq_u32(
                vandq_u32(
                    vandq_u32(
                        vcgtq_f32(cz, vmulq_laneq_f32::<3>(n, m4)),
                        vcltq_f32(r2, v(r2max)),
                    ),
                    vandq_u32(vcgeq_f32(u, zero), vcltq_f32(u, v(wf))),
                ),
                vandq_u32(vcgeq_f32(vv, zero), vcltq_f32(vv, v(hf))),
            );
            // pixel_index: on ok lanes u, v are in [0, 2^24), where `fcvtzs` truncates exactly
            // as the scalar conversion does. Unlike the scalar `to_int_unchecked`, `fcvtzs` is
            // defined for every input (it saturates, NaN gives 0), so the not-ok lanes need no
            // clamping first: whatever they compute, the select below replaces it by `sentinel`.
            let ui = vreinterpretq_u32_s32(vcvtq_s32_f32(u));
            let vi = vreinterpretq_u32_s32(vcvtq_s32_f32(vv));
            let idx = vaddq_u32(vmulq_u32(vi, vdupq_n_u32(w as u32)), ui);
            let res = vbslq_u32(ok, idx, vdupq_n_u32(sentinel));
            vst1q_u32(out.as_mut_ptr().add(i), res);
        }
        i += 4;
    }
    project_chunk_mei::<true>(
        &xs[body..n_all],
        &ys[body..n_all],
        &zs[body..n_all],
        p,
        m,
        t,
        &mut out[body..n_all],
    );
}
