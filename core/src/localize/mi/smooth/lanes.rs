//! The smooth estimator's chunk projection: up to [`CHUNK`] points rotated into the camera frame
//! and projected by the Mei model in f64, several points per instruction — the pixel for the value
//! passes; pixel, camera-frame point and the Jacobian's rows for the gradient passes. One body
//! ([`mei_step`]) is written over a lane type ([`Lanes`]) and compiled three times: the portable
//! loop (one lane), an AVX2 copy (x86-64, four lanes, chosen at run time) and a NEON copy
//! (aarch64, two lanes). The reference is the scalar [`camera_point`] then [`Proj::project_uv`] or
//! [`Proj::project`]: every lane performs its IEEE operations in the same order and association
//! (plain multiplies and adds, never a fused multiply-add; correctly rounded square root and
//! division), so a visible point's pixel and Jacobian are the reference's to the last bit and the
//! same points are visible. [`self_test`] checks that on the running CPU (`infraloc self-test`,
//! which CI also runs on the aarch64 binary under qemu and on the x86-64 binary on an emulated
//! CPU without AVX2).
//!
//! The equidistant model needs `atan2`, which has no vector instruction; its chunks go through the
//! scalar reference point by point.

use super::{Proj, CHUNK};

/// A pose as `X_c = R·p + t` on origin-shifted points: `r` row-major.
#[derive(Debug, Clone, Copy)]
pub(super) struct Rt {
    pub(super) r: [f64; 9],
    pub(super) t: [f64; 3],
}

/// One chunk's projections: pixel (u, v) and whether the model sees the point (`ok`); u and v of
/// a point it does not see are unspecified.
#[derive(Debug, Clone, Copy)]
pub(super) struct UvChunk {
    pub(super) u: [f64; CHUNK],
    pub(super) v: [f64; CHUNK],
    pub(super) ok: [bool; CHUNK],
}

impl Default for UvChunk {
    fn default() -> Self {
        UvChunk {
            u: [0.0; CHUNK],
            v: [0.0; CHUNK],
            ok: [false; CHUNK],
        }
    }
}

/// The Mei model's constants, as [`Proj::Mei`] holds them.
#[derive(Debug, Clone, Copy)]
struct Mei {
    k: [f64; 5],
    xi: f64,
    d: [f64; 4],
    zmin: f64,
    r2max: f64,
}

/// Which copy the smooth estimator's chunk projection runs for the Mei model on this CPU: `neon` (aarch64),
/// `avx2` (x86-64 with AVX2, detected at run time) or `portable`.
pub fn lanes_path() -> &'static str {
    #[cfg(target_arch = "aarch64")]
    return "neon";
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        return "avx2";
    }
    #[allow(unreachable_code)]
    "portable"
}

/// Project the points `xs`, `ys`, `zs` (origin-shifted, at most [`CHUNK`]) at `rt` into `out`'s
/// first entries (a [`UvChunk`], or a [`JacChunk`] for the Jacobian too): the Mei model by the
/// copy of [`lanes_path`], the equidistant one point by point.
pub(super) fn project_chunk<O: ChunkOut>(
    proj: &Proj,
    rt: &Rt,
    xs: &[f32],
    ys: &[f32],
    zs: &[f32],
    out: &mut O,
) {
    let Some(m) = mei_of(proj) else {
        return project_reference(proj, rt, xs, ys, zs, out);
    };
    #[cfg(target_arch = "aarch64")]
    {
        mei_neon(rt, &m, xs, ys, zs, out);
    }
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2 (checked on the line above).
            unsafe { mei_avx2(rt, &m, xs, ys, zs, out) };
        } else {
            mei_portable(rt, &m, xs, ys, zs, out);
        }
    }
    #[cfg(not(any(target_arch = "aarch64", target_arch = "x86_64")))]
    {
        mei_portable(rt, &m, xs, ys, zs, out);
    }
}

/// [`project_chunk`] with the portable lane loop whatever the CPU (the self-test's second copy).
fn project_portable<O: ChunkOut>(
    proj: &Proj,
    rt: &Rt,
    xs: &[f32],
    ys: &[f32],
    zs: &[f32],
    out: &mut O,
) {
    match mei_of(proj) {
        Some(m) => mei_portable(rt, &m, xs, ys, zs, out),
        None => project_reference(proj, rt, xs, ys, zs, out),
    }
}

/// The Mei model's constants of `proj`, if it is that model.
fn mei_of(proj: &Proj) -> Option<Mei> {
    match *proj {
        Proj::Mei {
            k,
            xi,
            d,
            zmin,
            r2max,
        } => Some(Mei {
            k,
            xi,
            d,
            zmin,
            r2max,
        }),
        Proj::Equidistant { .. } => None,
    }
}

/// The reference: [`camera_point`] then [`Proj::project_uv`] (or [`Proj::project`] when `out`
/// takes the Jacobian), point by point.
pub(super) fn project_reference<O: ChunkOut>(
    proj: &Proj,
    rt: &Rt,
    xs: &[f32],
    ys: &[f32],
    zs: &[f32],
    out: &mut O,
) {
    let n = chunk_len(xs, ys, zs);
    for i in 0..n {
        let xc = camera_point(rt, xs[i], ys[i], zs[i]);
        let seen = if let Some(jac) = out.jac() {
            proj.project(xc).map(|(uv, j)| {
                for c in 0..3 {
                    jac.xc[c][i] = xc[c];
                    jac.ju[c][i] = j[0][c];
                    jac.jv[c][i] = j[1][c];
                }
                uv
            })
        } else {
            proj.project_uv(xc)
        };
        let uv = out.uv();
        match seen {
            Some([u, v]) => {
                uv.u[i] = u;
                uv.v[i] = v;
                uv.ok[i] = true;
            }
            None => uv.ok[i] = false,
        }
    }
}

/// `R·p + t` row by row, each row's products added left to right (nalgebra's order: the tests
/// hold the two equal bit for bit).
#[inline(always)]
pub(super) fn camera_point(rt: &Rt, x: f32, y: f32, z: f32) -> [f64; 3] {
    let (x, y, z) = (x as f64, y as f64, z as f64);
    let r = &rt.r;
    [
        r[0] * x + r[1] * y + r[2] * z + rt.t[0],
        r[3] * x + r[4] * y + r[5] * z + rt.t[1],
        r[6] * x + r[7] * y + r[8] * z + rt.t[2],
    ]
}

fn chunk_len(xs: &[f32], ys: &[f32], zs: &[f32]) -> usize {
    xs.len().min(ys.len()).min(zs.len()).min(CHUNK)
}

/// The arithmetic the Mei copies share: one lane (`f64`, the portable loop), four
/// (`Avx2`) or two (`Neon`). Each operation is one correctly rounded IEEE operation per lane,
/// never fused with another, so one body written over this trait performs the same operations on
/// every copy.
trait Lanes: Copy {
    /// Points per step.
    const N: usize;
    /// A per-lane flag.
    type Mask: Copy;
    fn splat(v: f64) -> Self;
    /// `N` f32 from `s[i..]`, each widened to f64 (exact).
    fn load(s: &[f32], i: usize) -> Self;
    fn add(self, o: Self) -> Self;
    fn sub(self, o: Self) -> Self;
    /// The sign flipped (exact, as unary minus).
    fn neg(self) -> Self;
    fn mul(self, o: Self) -> Self;
    fn div(self, o: Self) -> Self;
    fn sqrt(self) -> Self;
    /// `self > o` (false on NaN).
    fn gt(self, o: Self) -> Self::Mask;
    /// `self < o` (false on NaN).
    fn lt(self, o: Self) -> Self::Mask;
    /// `!(self <= o)` (true on NaN).
    fn not_le(self, o: Self) -> Self::Mask;
    /// `!(self >= o)` (true on NaN).
    fn not_ge(self, o: Self) -> Self::Mask;
    fn and(a: Self::Mask, b: Self::Mask) -> Self::Mask;
    /// Store the `N` lanes at `out[i..]`.
    fn store(self, out: &mut [f64], i: usize);
    /// Store the `N` flags at `out[i..]`.
    fn store_mask(m: Self::Mask, out: &mut [bool], i: usize);
}

impl Lanes for f64 {
    const N: usize = 1;
    type Mask = bool;
    #[inline(always)]
    fn splat(v: f64) -> Self {
        v
    }
    #[inline(always)]
    fn load(s: &[f32], i: usize) -> Self {
        s[i] as f64
    }
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        self + o
    }
    #[inline(always)]
    fn sub(self, o: Self) -> Self {
        self - o
    }
    #[inline(always)]
    fn neg(self) -> Self {
        -self
    }
    #[inline(always)]
    fn mul(self, o: Self) -> Self {
        self * o
    }
    #[inline(always)]
    fn div(self, o: Self) -> Self {
        self / o
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        self.sqrt()
    }
    #[inline(always)]
    fn gt(self, o: Self) -> bool {
        self > o
    }
    #[inline(always)]
    fn lt(self, o: Self) -> bool {
        self < o
    }
    #[inline(always)]
    fn not_le(self, o: Self) -> bool {
        !(self <= o)
    }
    #[inline(always)]
    fn not_ge(self, o: Self) -> bool {
        !(self >= o)
    }
    #[inline(always)]
    fn and(a: bool, b: bool) -> bool {
        a & b
    }
    #[inline(always)]
    fn store(self, out: &mut [f64], i: usize) {
        out[i] = self;
    }
    #[inline(always)]
    fn store_mask(m: bool, out: &mut [bool], i: usize) {
        out[i] = m;
    }
}

/// The Mei model's operations on one step of `L::N` points from `i`: [`Proj::project_uv`] of
/// [`camera_point`] in its order and association, its three refusals (`n` not positive and
/// finite, the ray at or below `zmin`, r² at or past `r2max`) one flag. Writes u, v and the flag
/// at `out[i..]`.
#[inline(always)]
fn mei_step<L: Lanes, O: ChunkOut>(
    rt: &Rt,
    m: &Mei,
    xs: &[f32],
    ys: &[f32],
    zs: &[f32],
    i: usize,
    out: &mut O,
) {
    let b = L::splat;
    let (x, y, z) = (L::load(xs, i), L::load(ys, i), L::load(zs, i));
    // A closure would not inherit `inline(always)`: its lanes would cross a call without the
    // copy's target feature.
    #[inline(always)]
    fn row<L: Lanes>(rt: &Rt, j: usize, x: L, y: L, z: L) -> L {
        let (r, b) = (&rt.r, L::splat);
        b(r[3 * j])
            .mul(x)
            .add(b(r[3 * j + 1]).mul(y))
            .add(b(r[3 * j + 2]).mul(z))
            .add(b(rt.t[j]))
    }
    let (cx, cy, cz) = (
        row(rt, 0, x, y, z),
        row(rt, 1, x, y, z),
        row(rt, 2, x, y, z),
    );
    let n = cx.mul(cx).add(cy.mul(cy)).add(cz.mul(cz)).sqrt();
    let ok = L::and(n.gt(b(0.0)), n.lt(b(f64::INFINITY)));
    let (s0, s1, s2) = (cx.div(n), cy.div(n), cz.div(n));
    let ok = L::and(ok, s2.not_le(b(m.zmin)));
    let den = s2.add(b(m.xi));
    let (px, py) = (s0.div(den), s1.div(den));
    let r2 = px.mul(px).add(py.mul(py));
    let ok = L::and(ok, r2.not_ge(b(m.r2max)));
    let [k1, k2, p1, p2] = m.d;
    let two = b(2.0);
    let radial = b(1.0).add(b(k1).mul(r2)).add(b(k2).mul(r2).mul(r2));
    let xd = px
        .mul(radial)
        .add(b(2.0 * p1).mul(px).mul(py))
        .add(b(p2).mul(r2.add(two.mul(px).mul(px))));
    let yd = py
        .mul(radial)
        .add(b(p1).mul(r2.add(two.mul(py).mul(py))))
        .add(b(2.0 * p2).mul(px).mul(py));
    let k = m.k;
    let uv = out.uv();
    b(k[0])
        .mul(xd)
        .add(b(k[2]).mul(yd))
        .add(b(k[3]))
        .store(&mut uv.u, i);
    b(k[1]).mul(yd).add(b(k[4])).store(&mut uv.v, i);
    L::store_mask(ok, &mut uv.ok, i);
    let Some(jac) = out.jac() else {
        return;
    };
    // The Jacobian, as `Proj::project` forms it: ∂(xd, yd)/∂(x, y) …
    let dr = b(k1).add(b(2.0 * k2).mul(r2));
    let (drx, dry) = (two.mul(px).mul(dr), two.mul(py).mul(dr));
    let a = radial
        .add(px.mul(drx))
        .add(b(2.0 * p1).mul(py))
        .add(b(6.0 * p2).mul(px));
    let bb = px
        .mul(dry)
        .add(b(2.0 * p1).mul(px))
        .add(b(2.0 * p2).mul(py));
    let c = py
        .mul(drx)
        .add(b(2.0 * p1).mul(px))
        .add(b(2.0 * p2).mul(py));
    let e = radial
        .add(py.mul(dry))
        .add(b(6.0 * p1).mul(py))
        .add(b(2.0 * p2).mul(px));
    // … ∂(x, y)/∂s, then ∂s/∂p = (I − s sᵀ)/n, summed from 0.0 as the reference's loop does.
    let inv = b(1.0).div(den);
    let dxs = [inv, b(0.0), px.neg().div(den)];
    let dys = [b(0.0), inv, py.neg().div(den)];
    let sv = [s0, s1, s2];
    for j in 0..3 {
        let (mut gx, mut gy) = (b(0.0), b(0.0));
        for i2 in 0..3 {
            let delta = b(if i2 == j { 1.0 } else { 0.0 });
            let mm = delta.sub(sv[i2].mul(sv[j])).div(n);
            gx = gx.add(dxs[i2].mul(mm));
            gy = gy.add(dys[i2].mul(mm));
        }
        let dxd = a.mul(gx).add(bb.mul(gy));
        let dyd = c.mul(gx).add(e.mul(gy));
        b(k[0])
            .mul(dxd)
            .add(b(k[2]).mul(dyd))
            .store(&mut jac.ju[j], i);
        b(k[1]).mul(dyd).store(&mut jac.jv[j], i);
    }
    cx.store(&mut jac.xc[0], i);
    cy.store(&mut jac.xc[1], i);
    cz.store(&mut jac.xc[2], i);
}

/// Where a step writes: the pixels and flags, and for the gradient passes the camera-frame
/// points and the Jacobian's rows.
pub(super) trait ChunkOut {
    fn uv(&mut self) -> &mut UvChunk;
    fn jac(&mut self) -> Option<&mut JacParts>;
}

impl ChunkOut for UvChunk {
    #[inline(always)]
    fn uv(&mut self) -> &mut UvChunk {
        self
    }
    #[inline(always)]
    fn jac(&mut self) -> Option<&mut JacParts> {
        None
    }
}

/// The gradient passes' part of a chunk: per point its camera-frame point `xc` and the rows
/// ∂u/∂X_c (`ju`) and ∂v/∂X_c (`jv`), component-major; unspecified where the point is not seen.
#[derive(Debug, Clone, Copy)]
pub(super) struct JacParts {
    pub(super) xc: [[f64; CHUNK]; 3],
    pub(super) ju: [[f64; CHUNK]; 3],
    pub(super) jv: [[f64; CHUNK]; 3],
}

/// A chunk with its Jacobian (what [`project_chunk`] fills for the gradient passes).
#[derive(Debug, Clone, Copy)]
pub(super) struct JacChunk {
    pub(super) uv: UvChunk,
    pub(super) parts: JacParts,
}

impl Default for JacChunk {
    fn default() -> Self {
        JacChunk {
            uv: UvChunk::default(),
            parts: JacParts {
                xc: [[0.0; CHUNK]; 3],
                ju: [[0.0; CHUNK]; 3],
                jv: [[0.0; CHUNK]; 3],
            },
        }
    }
}

impl ChunkOut for JacChunk {
    #[inline(always)]
    fn uv(&mut self) -> &mut UvChunk {
        &mut self.uv
    }
    #[inline(always)]
    fn jac(&mut self) -> Option<&mut JacParts> {
        Some(&mut self.parts)
    }
}

/// [`mei_step`] over every point, `L::N` at a time, the rest one by one.
#[inline(always)]
fn mei_chunk<L: Lanes, O: ChunkOut>(
    rt: &Rt,
    m: &Mei,
    xs: &[f32],
    ys: &[f32],
    zs: &[f32],
    out: &mut O,
) {
    let n = chunk_len(xs, ys, zs);
    let body = n - n % L::N;
    for i in (0..body).step_by(L::N) {
        mei_step::<L, O>(rt, m, xs, ys, zs, i, out);
    }
    for i in body..n {
        mei_step::<f64, O>(rt, m, xs, ys, zs, i, out);
    }
}

/// The portable copy: one lane.
fn mei_portable<O: ChunkOut>(rt: &Rt, m: &Mei, xs: &[f32], ys: &[f32], zs: &[f32], out: &mut O) {
    mei_chunk::<f64, O>(rt, m, xs, ys, zs, out);
}

/// The arithmetic methods every vector copy writes alike, one intrinsic each: add, sub, mul,
/// div (lane-wise, correctly rounded) and sqrt.
macro_rules! lane_ops {
    ($wrap:ident; $add:ident, $sub:ident, $mul:ident, $div:ident, $sqrt:ident) => {
        #[inline(always)]
        fn add(self, o: Self) -> Self {
            // SAFETY: the type exists only where its instructions run (see its impl).
            $wrap(unsafe { $add(self.0, o.0) })
        }
        #[inline(always)]
        fn sub(self, o: Self) -> Self {
            // SAFETY: as for `add`.
            $wrap(unsafe { $sub(self.0, o.0) })
        }
        #[inline(always)]
        fn mul(self, o: Self) -> Self {
            // SAFETY: as for `add`.
            $wrap(unsafe { $mul(self.0, o.0) })
        }
        #[inline(always)]
        fn div(self, o: Self) -> Self {
            // SAFETY: as for `add`.
            $wrap(unsafe { $div(self.0, o.0) })
        }
        #[inline(always)]
        fn sqrt(self) -> Self {
            // SAFETY: as for `add`.
            $wrap(unsafe { $sqrt(self.0) })
        }
    };
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::*;
    use core::arch::x86_64::*;

    /// Four lanes of AVX2. Only [`mei_avx2`] makes one, after the CPU was found to have AVX2;
    /// the methods inline into it, so their intrinsics run with the feature enabled.
    #[derive(Clone, Copy)]
    pub(super) struct Avx2(__m256d);

    // SAFETY (every method): an `Avx2` exists only inside `mei_avx2`, which runs on a CPU with
    // AVX2; loads read four f32 at i + 4 ≤ the slice's length and stores write four lanes at
    // i + 4 ≤ the slice's length (asserted).
    impl Lanes for Avx2 {
        const N: usize = 4;
        type Mask = Avx2;
        lane_ops!(Avx2; _mm256_add_pd, _mm256_sub_pd, _mm256_mul_pd, _mm256_div_pd, _mm256_sqrt_pd);
        #[inline(always)]
        fn splat(v: f64) -> Self {
            // SAFETY: an `Avx2` exists only on a CPU with AVX2 (see the impl).
            Avx2(unsafe { _mm256_set1_pd(v) })
        }
        #[inline(always)]
        fn load(s: &[f32], i: usize) -> Self {
            assert!(i + 4 <= s.len());
            // SAFETY: an `Avx2` exists only on a CPU with AVX2 (see the impl); bounds asserted above.
            Avx2(unsafe { _mm256_cvtps_pd(_mm_loadu_ps(s.as_ptr().add(i))) })
        }
        #[inline(always)]
        fn neg(self) -> Self {
            // SAFETY: an `Avx2` exists only on a CPU with AVX2 (see the impl).
            Avx2(unsafe { _mm256_xor_pd(self.0, _mm256_set1_pd(-0.0)) })
        }
        #[inline(always)]
        fn gt(self, o: Self) -> Self {
            // SAFETY: an `Avx2` exists only on a CPU with AVX2 (see the impl).
            Avx2(unsafe { _mm256_cmp_pd::<_CMP_GT_OQ>(self.0, o.0) })
        }
        #[inline(always)]
        fn lt(self, o: Self) -> Self {
            // SAFETY: an `Avx2` exists only on a CPU with AVX2 (see the impl).
            Avx2(unsafe { _mm256_cmp_pd::<_CMP_LT_OQ>(self.0, o.0) })
        }
        #[inline(always)]
        fn not_le(self, o: Self) -> Self {
            // SAFETY: an `Avx2` exists only on a CPU with AVX2 (see the impl).
            Avx2(unsafe { _mm256_cmp_pd::<_CMP_NLE_UQ>(self.0, o.0) })
        }
        #[inline(always)]
        fn not_ge(self, o: Self) -> Self {
            // SAFETY: an `Avx2` exists only on a CPU with AVX2 (see the impl).
            Avx2(unsafe { _mm256_cmp_pd::<_CMP_NGE_UQ>(self.0, o.0) })
        }
        #[inline(always)]
        fn and(a: Self, b: Self) -> Self {
            // SAFETY: an `Avx2` exists only on a CPU with AVX2 (see the impl).
            Avx2(unsafe { _mm256_and_pd(a.0, b.0) })
        }
        #[inline(always)]
        fn store(self, out: &mut [f64], i: usize) {
            assert!(i + 4 <= out.len());
            // SAFETY: an `Avx2` exists only on a CPU with AVX2 (see the impl); bounds asserted above.
            unsafe { _mm256_storeu_pd(out.as_mut_ptr().add(i), self.0) }
        }
        #[inline(always)]
        fn store_mask(m: Self, out: &mut [bool], i: usize) {
            // SAFETY: an `Avx2` exists only on a CPU with AVX2 (see the impl).
            let bits = unsafe { _mm256_movemask_pd(m.0) };
            for (l, o) in out[i..i + 4].iter_mut().enumerate() {
                *o = bits & (1 << l) != 0;
            }
        }
    }

    /// [`mei_chunk`] four points per step.
    ///
    /// # Safety
    /// The CPU must support AVX2.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn mei_avx2<O: ChunkOut>(
        rt: &Rt,
        m: &Mei,
        xs: &[f32],
        ys: &[f32],
        zs: &[f32],
        out: &mut O,
    ) {
        mei_chunk::<Avx2, O>(rt, m, xs, ys, zs, out);
    }
}
#[cfg(target_arch = "x86_64")]
use avx2::mei_avx2;

#[cfg(target_arch = "aarch64")]
mod neon {
    use super::*;
    use core::arch::aarch64::*;

    /// Two lanes of NEON (in the aarch64 baseline). `vmulq` and `vaddq` are never fused here.
    #[derive(Clone, Copy)]
    pub(super) struct Neon(float64x2_t);

    // SAFETY (every method): NEON is part of the aarch64-unknown-linux-gnu baseline; loads read
    // two f32 at i + 2 ≤ the slice's length and stores write two lanes at i + 2 ≤ the slice's
    // length (asserted).
    impl Lanes for Neon {
        const N: usize = 2;
        type Mask = uint64x2_t;
        lane_ops!(Neon; vaddq_f64, vsubq_f64, vmulq_f64, vdivq_f64, vsqrtq_f64);
        #[inline(always)]
        fn splat(v: f64) -> Self {
            // SAFETY: NEON is in the aarch64 baseline (see the impl).
            Neon(unsafe { vdupq_n_f64(v) })
        }
        #[inline(always)]
        fn load(s: &[f32], i: usize) -> Self {
            assert!(i + 2 <= s.len());
            // SAFETY: NEON is in the aarch64 baseline (see the impl); bounds asserted above.
            Neon(unsafe { vcvt_f64_f32(vld1_f32(s.as_ptr().add(i))) })
        }
        #[inline(always)]
        fn neg(self) -> Self {
            // SAFETY: NEON is in the aarch64 baseline (see the impl).
            Neon(unsafe { vnegq_f64(self.0) })
        }
        #[inline(always)]
        fn gt(self, o: Self) -> uint64x2_t {
            // SAFETY: NEON is in the aarch64 baseline (see the impl).
            unsafe { vcgtq_f64(self.0, o.0) }
        }
        #[inline(always)]
        fn lt(self, o: Self) -> uint64x2_t {
            // SAFETY: NEON is in the aarch64 baseline (see the impl).
            unsafe { vcltq_f64(self.0, o.0) }
        }
        #[inline(always)]
        fn not_le(self, o: Self) -> uint64x2_t {
            // All ones where `self <= o` is false (NaN included).
            // SAFETY: NEON is in the aarch64 baseline (see the impl).
            unsafe { vbicq_u64(vdupq_n_u64(u64::MAX), vcleq_f64(self.0, o.0)) }
        }
        #[inline(always)]
        fn not_ge(self, o: Self) -> uint64x2_t {
            // SAFETY: NEON is in the aarch64 baseline (see the impl).
            unsafe { vbicq_u64(vdupq_n_u64(u64::MAX), vcgeq_f64(self.0, o.0)) }
        }
        #[inline(always)]
        fn and(a: uint64x2_t, b: uint64x2_t) -> uint64x2_t {
            // SAFETY: NEON is in the aarch64 baseline (see the impl).
            unsafe { vandq_u64(a, b) }
        }
        #[inline(always)]
        fn store(self, out: &mut [f64], i: usize) {
            assert!(i + 2 <= out.len());
            // SAFETY: NEON is in the aarch64 baseline (see the impl); bounds asserted above.
            unsafe { vst1q_f64(out.as_mut_ptr().add(i), self.0) }
        }
        #[inline(always)]
        fn store_mask(m: uint64x2_t, out: &mut [bool], i: usize) {
            // SAFETY: NEON is in the aarch64 baseline (see the impl).
            out[i] = unsafe { vgetq_lane_u64::<0>(m) } != 0;
            // SAFETY: NEON is in the aarch64 baseline (see the impl).
            out[i + 1] = unsafe { vgetq_lane_u64::<1>(m) } != 0;
        }
    }

    /// [`mei_chunk`] two points per step.
    pub(super) fn mei_neon<O: ChunkOut>(
        rt: &Rt,
        m: &Mei,
        xs: &[f32],
        ys: &[f32],
        zs: &[f32],
        out: &mut O,
    ) {
        mei_chunk::<Neon, O>(rt, m, xs, ys, zs, out);
    }
}
#[cfg(target_arch = "aarch64")]
use neon::mei_neon;

/// What [`self_test`] compared.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LanesTest {
    /// [`lanes_path`].
    pub path: &'static str,
    /// Points projected per pose.
    pub points: usize,
    /// Poses compared.
    pub poses: usize,
}

/// Check, on this CPU, that the smooth estimator's Mei chunk projection ([`lanes_path`]'s copy
/// and the portable lane loop) gives the reference's visibility and, for every visible point, its
/// pixel, camera point and Jacobian bit for bit, and that the estimator's value and gradient are
/// the reference's, over `poses` poses of the nearest-pixel kernel's self-test scene (a `5mp` Mei
/// camera; points behind and past the 92.5° limit included). `Err` names the first pose (and
/// point) that differs.
pub fn self_test(
    poses: usize,
) -> std::result::Result<LanesTest, crate::localize::error::SelfTestError> {
    use crate::localize::error::SelfTestError;
    use crate::localize::mi::kernel::selftest::{test_camera_mei, test_pose_f64, test_scene};
    let cam = test_camera_mei();
    let (pts, img, origin) = test_scene(&cam);
    let proj = Proj::new(&cam);
    let (mut seen, mut lost) = (0usize, 0usize);
    for j in 0..poses {
        let rt = rt_of(&test_pose_f64(j), origin);
        for c0 in (0..pts.len()).step_by(CHUNK) {
            let e = (c0 + CHUNK).min(pts.len());
            let (xs, ys, zs) = (&pts.x[c0..e], &pts.y[c0..e], &pts.z[c0..e]);
            let differs =
                |what: &'static str, (i, copy): (usize, &'static str)| SelfTestError::Lanes {
                    pose: j,
                    point: c0 + i,
                    copy,
                    what,
                };
            let visible = same_chunks::<UvChunk>(&proj, &rt, xs, ys, zs)
                .map_err(|e| differs("projection", e))?;
            same_chunks::<JacChunk>(&proj, &rt, xs, ys, zs).map_err(|e| differs("Jacobian", e))?;
            seen += visible;
            lost += e - c0 - visible;
        }
    }
    if seen == 0 || lost == 0 {
        return Err(SelfTestError::Degenerate {
            seen: seen as u64,
            seen_word: "visible",
            lost: lost as u64,
            lost_word: "not",
        });
    }
    // And the estimator built on them: its value, MI and gradient at every pose, bit for bit.
    let (fast, reference) = (estimator(&cam, &pts, &img), estimator(&cam, &pts, &img));
    let reference = reference.with_reference_projection();
    for j in 0..poses {
        let pose = test_pose_f64(j);
        if fast.evaluate(&pose, true) != reference.evaluate(&pose, true) {
            return Err(SelfTestError::LanesEstimator {
                pose: j,
                path: lanes_path(),
            });
        }
    }
    Ok(LanesTest {
        path: lanes_path(),
        points: pts.len(),
        poses,
    })
}

/// Whether [`project_chunk`] into an `O` ([`UvChunk`], or [`JacChunk`] with the Jacobian) on
/// this CPU's copy and on the portable loop equals the reference bit for bit on these points:
/// visibility, and where seen the pixel (and the camera point and both rows). `Ok`: how many the
/// reference sees; `Err`: the first point that differs and the copy.
fn same_chunks<O: ChunkOut + Default>(
    proj: &Proj,
    rt: &Rt,
    xs: &[f32],
    ys: &[f32],
    zs: &[f32],
) -> std::result::Result<usize, (usize, &'static str)> {
    let (mut got, mut port, mut want) = (O::default(), O::default(), O::default());
    project_chunk(proj, rt, xs, ys, zs, &mut got);
    project_portable(proj, rt, xs, ys, zs, &mut port);
    project_reference(proj, rt, xs, ys, zs, &mut want);
    let bits = |c: &mut O, i: usize| -> (bool, Vec<u64>) {
        let uv = c.uv();
        let (ok, mut v) = (uv.ok[i], vec![uv.u[i].to_bits(), uv.v[i].to_bits()]);
        if let Some(q) = c.jac() {
            for a in [&q.xc, &q.ju, &q.jv] {
                v.extend(a.iter().map(|r| r[i].to_bits()));
            }
        }
        (ok, v)
    };
    let mut seen = 0;
    for i in 0..chunk_len(xs, ys, zs) {
        let (ok, reference) = bits(&mut want, i);
        for (copy, c) in [(lanes_path(), &mut got), ("portable", &mut port)] {
            let (c_ok, c_bits) = bits(c, i);
            if c_ok != ok || (ok && c_bits != reference) {
                return Err((i, copy));
            }
        }
        seen += usize::from(ok);
    }
    Ok(seen)
}

/// The self-test scene's estimator: one view, 32 × 32 bins with Parzen smoothing, its points'
/// origin the scene's.
fn estimator<'a>(
    cam: &crate::camera::Camera,
    pts: &'a crate::localize::mi::points::PreparedPoints,
    img: &'a crate::localize::mi::kernel::BinnedImage,
) -> super::Smooth<'a> {
    let origin = crate::localize::mi::kernel::selftest::test_scene_origin();
    let view = super::SmoothView { img, pts };
    super::Smooth::new(cam, vec![view], origin, 32, 32, true, super::Pooling::Joint)
}

/// The PV workload beside the nearest-pixel one (docs/benchmarks.md "The smooth estimator"):
/// `poses` values with the gradient (the ascent's unit of work) of the self-test scene's estimator, with this CPU's chunk projection or
/// (`reference`) the scalar reference. Returns the points and a checksum of the values.
pub fn workload(poses: usize, reference: bool) -> (usize, u64) {
    use crate::localize::mi::kernel::selftest::{test_camera_mei, test_pose_f64, test_scene};
    let cam = test_camera_mei();
    let (pts, img, _) = test_scene(&cam);
    let mut est = estimator(&cam, &pts, &img);
    if reference {
        est = est.with_reference_projection();
    }
    let mut sum = 0u64;
    for j in 0..poses {
        let v = est.evaluate(&test_pose_f64(j), true);
        let g = v.grad.unwrap_or_default();
        sum = sum
            .wrapping_mul(31)
            .wrapping_add(v.value.to_bits() ^ g[0].to_bits());
    }
    (pts.len(), sum)
}

/// `X_c = R·p + t` of `pose` for points shifted by `origin` (as the estimator forms it).
fn rt_of(pose: &crate::pose::CamFromMap, origin: [f64; 3]) -> Rt {
    let o = nalgebra::Point3::new(origin[0], origin[1], origin[2]);
    Rt::of(pose.rotation.matrix(), &pose.transform(&o).coords)
}

impl Rt {
    /// From nalgebra's R and t.
    pub(super) fn of(r: &nalgebra::Matrix3<f64>, t: &nalgebra::Vector3<f64>) -> Self {
        Rt {
            r: std::array::from_fn(|k| r[(k / 3, k % 3)]),
            t: [t.x, t.y, t.z],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The lanes' camera-frame point is nalgebra's `R·p + t` bit for bit (the reference the
    /// gradient passes use), on points spread over magnitudes and signs.
    #[test]
    fn camera_point_is_nalgebra_s_bit_for_bit() {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        for j in 0..50 {
            let pose = crate::localize::mi::kernel::selftest::test_pose_f64(j);
            let origin = [10.3 + next(), 19.8 + next(), 6.0 + next()];
            let rt = rt_of(&pose, origin);
            let o = nalgebra::Point3::new(origin[0], origin[1], origin[2]);
            let (r, t) = (*pose.rotation.matrix(), pose.transform(&o).coords);
            for _ in 0..200 {
                let (x, y, z) = (
                    (next() * 80.0) as f32,
                    (next() * 80.0) as f32,
                    (next() * 9.0) as f32,
                );
                let want = r * nalgebra::Vector3::new(x as f64, y as f64, z as f64) + t;
                let got = camera_point(&rt, x, y, z);
                for k in 0..3 {
                    assert_eq!(got[k].to_bits(), want[k].to_bits(), "pose {j}, axis {k}");
                }
            }
        }
    }

    /// The equidistant model goes through the reference point by point: the same pixels, and
    /// the Jacobian chunk too.
    #[test]
    fn equidistant_chunks_are_the_reference_s() {
        use crate::localize::mi::kernel::selftest::{test_camera_equidistant, test_scene};
        let cam = test_camera_equidistant((1280, 1024), 400.0, (640.0, 512.0));
        let (pts, _, origin) = test_scene(&cam);
        let proj = Proj::new(&cam);
        let rt = rt_of(
            &crate::localize::mi::kernel::selftest::test_pose_f64(5),
            origin,
        );
        let (mut seen, mut unseen) = (0, 0);
        for c0 in (0..pts.len()).step_by(CHUNK) {
            let e = (c0 + CHUNK).min(pts.len());
            let (xs, ys, zs) = (&pts.x[c0..e], &pts.y[c0..e], &pts.z[c0..e]);
            assert!(
                same_chunks::<JacChunk>(&proj, &rt, xs, ys, zs).is_ok(),
                "chunk {c0}"
            );
            let mut got = UvChunk::default();
            project_chunk(&proj, &rt, xs, ys, zs, &mut got);
            seen += got.ok[..e - c0].iter().filter(|&&o| o).count();
            unseen += got.ok[..e - c0].iter().filter(|&&o| !o).count();
        }
        assert!(seen > 0 && unseen > 0, "{seen} seen, {unseen} not");
    }

    /// This CPU's copy and the portable lane loop equal the reference on the self-test scene.
    #[test]
    fn the_lanes_equal_the_reference_on_this_cpu() {
        let r = self_test(8).unwrap();
        assert_eq!(r.path, lanes_path());
        assert!(r.points > 10_000);
    }

    /// A chunk shorter than [`CHUNK`] and not a multiple of the lane count: the tail lanes go
    /// through the portable loop and still match, and entries past the chunk are left alone.
    #[test]
    fn short_chunks_match_and_leave_the_rest() {
        use crate::localize::mi::kernel::selftest::{test_camera_mei, test_scene};
        let cam = test_camera_mei();
        let (pts, _, origin) = test_scene(&cam);
        let proj = Proj::new(&cam);
        let rt = rt_of(
            &crate::localize::mi::kernel::selftest::test_pose_f64(3),
            origin,
        );
        for m in [1, 2, 3, 5, 7, CHUNK - 1] {
            let (mut got, mut want) = (UvChunk::default(), UvChunk::default());
            got.u[m..].fill(-7.0);
            let (xs, ys, zs) = (
                &pts.x[100..100 + m],
                &pts.y[100..100 + m],
                &pts.z[100..100 + m],
            );
            project_chunk(&proj, &rt, xs, ys, zs, &mut got);
            project_reference(&proj, &rt, xs, ys, zs, &mut want);
            assert_eq!(got.ok[..m], want.ok[..m], "m = {m}");
            for i in (0..m).filter(|&i| want.ok[i]) {
                assert_eq!(got.u[i].to_bits(), want.u[i].to_bits(), "m = {m}, u {i}");
                assert_eq!(got.v[i].to_bits(), want.v[i].to_bits(), "m = {m}, v {i}");
            }
            assert!(
                got.u[m..].iter().all(|&u| u == -7.0),
                "m = {m}: wrote past the chunk"
            );
            assert!(
                same_chunks::<JacChunk>(&proj, &rt, xs, ys, zs).is_ok(),
                "m = {m}"
            );
        }
    }
}
