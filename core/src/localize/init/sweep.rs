//! Learning-free matching of the fisheye's ground view against the satellite image, with unknown yaw
//! (full 360°) and unknown mounting height: a dense sweep.
//!
//! The fisheye image is first resampled once into a *nominal* bird's-eye view `B(q)` over normalised
//! ground offsets `q = offset / height` (a north-up nadir camera at unit height). A camera at height
//! `h` with yaw `ψ` then sees the map offset `u` at `B(Rz(−ψ)·u / h)`: every (ψ, h) hypothesis is a
//! rotated, scaled copy of `B`, and the camera position is a translation found by FFT correlation.
//!
//! Across the modality gap (satellite colour vs camera gray, different shadows) intensities do not
//! correlate, edges do. The feature is the *doubled-angle gradient orientation field*
//! `z = e^{2iθ}·s(|∇I|)`: squaring the direction makes it blind to contrast polarity (a marking
//! brighter than asphalt in one image and darker in the other still matches), and the soft
//! saturation `s` keeps a few strong shadow edges from dominating. Rotating the template by ψ turns
//! its feature phase by 2ψ, so the field of `B` is computed once and only resampled per hypothesis.
//!
//! Score: masked normalised correlation `Re Σ z_s·z̄_t / √(Σ_mask|z_s|² · Σ|z_t|²)`. The mask is a
//! disk whose radius depends on h only, so the local energy `Σ_mask|z_s|²` costs one FFT pair per
//! height, and each pair of hypotheses (ψ, h), (ψ + π, h) costs one forward and one inverse FFT
//! (the second template is the first reflected through its centre: [`YawPair`]).

use rayon::prelude::*;
use rustfft::num_complex::Complex32;
use rustfft::{Fft, FftPlanner};
use std::sync::Arc;

/// A single-channel f32 image, row-major.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct GrayF32 {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// `width × height` samples.
    pub data: Vec<f32>,
}

impl GrayF32 {
    /// A zero image.
    pub(crate) fn new(width: usize, height: usize) -> Self {
        GrayF32 {
            width,
            height,
            data: vec![0.0; width * height],
        }
    }

    #[inline]
    fn at(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.width + x]
    }
}

/// A complex feature field, row-major.
#[derive(Debug, Clone)]
pub(crate) struct Field {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Samples.
    pub data: Vec<Complex32>,
}

impl Field {
    /// Bilinear sample at continuous pixel coordinates (centres at integers); zero outside.
    #[inline]
    pub(crate) fn sample(&self, x: f32, y: f32) -> Complex32 {
        if !(x >= 0.0 && y >= 0.0) {
            return Complex32::new(0.0, 0.0);
        }
        let (x0, y0) = (x as usize, y as usize);
        if x0 + 1 >= self.width || y0 + 1 >= self.height {
            return Complex32::new(0.0, 0.0);
        }
        let (fx, fy) = (x - x0 as f32, y - y0 as f32);
        let i = y0 * self.width + x0;
        let top = self.data[i] * (1.0 - fx) + self.data[i + 1] * fx;
        let bot = self.data[i + self.width] * (1.0 - fx) + self.data[i + self.width + 1] * fx;
        top * (1.0 - fy) + bot * fy
    }

    /// Halve the resolution by 2×2 averaging (complex averaging: orientations that disagree
    /// cancel, which is what a coarser view of them should do).
    pub(crate) fn downsample2(&self) -> Field {
        let (w, h) = ((self.width / 2).max(1), (self.height / 2).max(1));
        let mut data = vec![Complex32::new(0.0, 0.0); w * h];
        for y in 0..h {
            for x in 0..w {
                let mut acc = Complex32::new(0.0, 0.0);
                for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    let (sx, sy) = (
                        (2 * x + dx).min(self.width - 1),
                        (2 * y + dy).min(self.height - 1),
                    );
                    acc += self.data[sy * self.width + sx];
                }
                data[y * w + x] = acc * 0.25;
            }
        }
        Field {
            width: w,
            height: h,
            data,
        }
    }
}

/// |z| as glibc's `hypotf` computes it for finite parts (the squares and their sum in f64,
/// rounded once to f32; the same bits as glibc 2.36's on 2·10⁸ random pairs), without the
/// library call (1.4 % of a `5mp` localization's CPU) and alike on every target.
#[inline]
fn magnitude(z: Complex32) -> f32 {
    let (re, im) = (f64::from(z.re), f64::from(z.im));
    (re * re + im * im).sqrt() as f32
}

/// Doubled-angle orientation field of an image. `valid` (same size, optional) marks pixels whose
/// 3×3 neighbourhood is real data; elsewhere the feature is zero so borders of the image circle or
/// no-data areas create no false edges.
pub(crate) fn orientation_field(img: &GrayF32, valid: Option<&[bool]>) -> Field {
    let (w, h) = (img.width, img.height);
    let mut data = vec![Complex32::new(0.0, 0.0); w * h];
    // Rows on the thread pool: each pixel's value is its own, and the magnitudes' percentile
    // below does not depend on their order.
    let mut mags: Vec<f32> = data
        .par_chunks_mut(w.max(1))
        .enumerate()
        .filter(|(y, _)| *y >= 1 && *y + 1 < h)
        .flat_map_iter(|(y, row)| {
            let mut mags = Vec::new();
            let inner = row.iter_mut().enumerate().take(w.saturating_sub(1)).skip(1);
            for (x, out) in inner {
                if let Some(v) = valid {
                    let ok = (y - 1..=y + 1).all(|yy| (x - 1..=x + 1).all(|xx| v[yy * w + xx]));
                    if !ok {
                        continue;
                    }
                }
                // Sobel.
                let gx = (img.at(x + 1, y - 1) + 2.0 * img.at(x + 1, y) + img.at(x + 1, y + 1))
                    - (img.at(x - 1, y - 1) + 2.0 * img.at(x - 1, y) + img.at(x - 1, y + 1));
                let gy = (img.at(x - 1, y + 1) + 2.0 * img.at(x, y + 1) + img.at(x + 1, y + 1))
                    - (img.at(x - 1, y - 1) + 2.0 * img.at(x, y - 1) + img.at(x + 1, y - 1));
                let g = Complex32::new(gx, gy);
                let m = magnitude(g);
                if m > 0.0 {
                    *out = g * g / m; // |·| = m, arg = 2θ
                    mags.push(m);
                }
            }
            mags
        })
        .collect();
    // Soft saturation at a robust scale: s(m) = m / (m + k), k = 80th-percentile magnitude.
    if !mags.is_empty() {
        let idx = mags.len() * 4 / 5;
        let k = *mags.select_nth_unstable_by(idx, f32::total_cmp).1;
        if k > 0.0 {
            data.par_iter_mut().for_each(|z| {
                let m = magnitude(*z);
                if m > 0.0 {
                    *z *= 1.0 / (m + k);
                }
            });
        }
    }
    Field {
        width: w,
        height: h,
        data,
    }
}

/// Square 2-D FFT of side `n` (rows, transpose, rows: spectra are kept transposed, which is fine
/// because they are only multiplied element-wise and transformed back by the same routine).
pub(crate) struct Fft2 {
    n: usize,
    fwd: Arc<dyn Fft<f32>>,
    inv: Arc<dyn Fft<f32>>,
}

impl Fft2 {
    /// Plan transforms of size `n × n`.
    pub(crate) fn new(n: usize) -> Self {
        let mut p = FftPlanner::new();
        Fft2 {
            n,
            fwd: p.plan_fft_forward(n),
            inv: p.plan_fft_inverse(n),
        }
    }

    /// Side length.
    pub(crate) fn size(&self) -> usize {
        self.n
    }

    /// Row transforms of the first `first` rows, transpose, row transforms of the first `second`
    /// rows (both at most n). Rows from `first` on must be zero on entry, and rows from
    /// `second` on are left unspecified: the transpose moves only what the second pass reads.
    fn run(
        &self,
        f: &Arc<dyn Fft<f32>>,
        buf: &mut [Complex32],
        scratch: &mut Vec<Complex32>,
        first: usize,
        second: usize,
    ) {
        let n = self.n;
        let (first, second) = (first.min(n), second.min(n));
        // rustfft's `process` allocates this scratch on every call; keep it across calls.
        scratch.resize(f.get_inplace_scratch_len(), Complex32::default());
        f.process_with_scratch(&mut buf[..first * n], scratch);
        transpose_pruned(buf, n, first, second);
        f.process_with_scratch(&mut buf[..second * n], scratch);
    }

    /// Forward transform in place (output transposed). `scratch` is reused between calls.
    pub(crate) fn forward(&self, buf: &mut [Complex32], scratch: &mut Vec<Complex32>) {
        self.run(&self.fwd, buf, scratch, self.n, self.n)
    }

    /// [`Fft2::forward`] of an image whose rows from `rows` on are all zero (a template in the
    /// corner of its padding): those rows' transforms are zero and are skipped. Bit-identical to
    /// `forward`.
    pub(crate) fn forward_top_rows(
        &self,
        buf: &mut [Complex32],
        scratch: &mut Vec<Complex32>,
        rows: usize,
    ) {
        self.run(&self.fwd, buf, scratch, rows, self.n)
    }

    /// Inverse transform in place of a transposed spectrum (output in image layout, unscaled:
    /// multiply by 1/n² for a true inverse). `scratch` is reused between calls.
    pub(crate) fn inverse(&self, buf: &mut [Complex32], scratch: &mut Vec<Complex32>) {
        self.run(&self.inv, buf, scratch, self.n, self.n)
    }

    /// [`Fft2::inverse`] whose output is needed in its first `rows` rows only (the valid shifts
    /// of a correlation): the rest are left unspecified. Those rows are bit-identical to
    /// `inverse`'s.
    pub(crate) fn inverse_top_rows(
        &self,
        buf: &mut [Complex32],
        scratch: &mut Vec<Complex32>,
        rows: usize,
    ) {
        self.run(&self.inv, buf, scratch, self.n, rows)
    }
}

/// The smallest n ≥ `size` (and ≥ 1) whose only prime factors are 2, 3 and 5.
pub(crate) fn fft_size(size: usize) -> usize {
    let smooth = |mut m: usize| {
        for p in [2, 3, 5] {
            while m % p == 0 {
                m /= p;
            }
        }
        m == 1
    };
    (size.max(1)..).find(|&m| smooth(m)).unwrap_or(size)
}

/// Side of the square blocks [`transpose`] swaps at a time: two 32×32 blocks of `Complex32`
/// (8 KiB each) stay in L1, where a whole column of a 512² spectrum (one cache line per element)
/// would not.
const TRANSPOSE_BLOCK: usize = 32;

/// `buf` (n × n, row-major) transposed in place by swapping mirrored elements, block by block
/// (pure data movement: the result is the same as the element-by-element loop's, without a copy).
#[cfg(test)]
fn transpose(buf: &mut [Complex32], n: usize) {
    transpose_pruned(buf, n, n, n)
}

/// [`transpose`] of a `buf` whose rows from `nonzero` on are zero, where only the first `keep`
/// rows of the result are wanted: mirrored pairs that are both zero stay, a pair with one zero
/// side is a copy and a zero, and a pair whose lower half lands in an unwanted row is a copy.
/// The first `keep` rows are those of the full transpose, and so are the others when `keep` is
/// n. (The sweep's templates fill a third of their rows; its correlations are read in two
/// thirds.)
fn transpose_pruned(buf: &mut [Complex32], n: usize, nonzero: usize, keep: usize) {
    let zero = Complex32::new(0.0, 0.0);
    // Pairs (i, j), i < j: element (i, j) goes to row j, (j, i) to row i. Rows i ≥ `nonzero`
    // pair only zeros. For i < `nonzero`: up to `split` both rows are data and wanted (a swap),
    // up to `nonzero` row j is unwanted (a copy into row i), beyond it row j is zero (a copy
    // into row j and a zero into row i).
    let split = nonzero.min(keep);
    for bi in (0..nonzero).step_by(TRANSPOSE_BLOCK) {
        for bj in (bi..n).step_by(TRANSPOSE_BLOCK) {
            let j1 = (bj + TRANSPOSE_BLOCK).min(n);
            for i in bi..(bi + TRANSPOSE_BLOCK).min(nonzero) {
                let j0 = if bi == bj { i + 1 } else { bj };
                for j in j0..j1.min(split) {
                    buf.swap(i * n + j, j * n + i);
                }
                for j in j0.max(split)..j1.min(nonzero) {
                    buf[i * n + j] = buf[j * n + i];
                }
                for j in j0.max(nonzero)..j1 {
                    buf[j * n + i] = buf[i * n + j];
                    buf[i * n + j] = zero;
                }
            }
        }
    }
}

/// One hypothesis of the sweep.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Candidate {
    /// Yaw ψ, radians.
    pub yaw: f64,
    /// Camera height above the ground, metres.
    pub height: f64,
    /// Camera position offset from the search centre, metres (east, north).
    pub offset: [f64; 2],
    /// Masked normalised correlation in [−1, 1].
    pub score: f64,
}

/// The nominal bird's-eye field: `B` over normalised offsets, centre at (`c`, `c`), step `dq`.
#[derive(Debug, Clone)]
pub(crate) struct NominalField {
    /// Field pyramid; level `l` has step `dq·2^l`.
    pub levels: Vec<Field>,
    /// Step of level 0 in normalised units (metres of ground offset per metre of height).
    pub dq: f64,
    /// Largest usable |q| (e.g. tan of 70°).
    pub q_max: f64,
}

/// Search settings of [`sweep`].
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct SweepParams {
    /// Yaw step, degrees.
    pub yaw_step_deg: f64,
    /// Heights to try, metres.
    pub heights: Vec<f64>,
    /// Largest template radius, metres (ground beyond it is too oblique to be useful).
    pub template_radius_m: f64,
    /// How many best candidates to return (after non-maximum suppression).
    pub top_k: usize,
    /// Largest candidate offset from the field's centre, metres (the prior's search radius; the
    /// field may be larger, to hold the template at the edge). `f64::INFINITY`: no limit.
    pub max_offset_m: f64,
}

impl SweepParams {
    /// Ground radius of the sweep's template, metres: one radius for every height (see
    /// [`sweep`]), what the lowest height sees within `q_max`, at most `template_radius_m`. The
    /// satellite field must reach this far beyond the search window.
    pub(crate) fn effective_template_radius_m(&self, q_max: f64) -> f64 {
        let h_min = self.heights.iter().copied().fold(f64::INFINITY, f64::min);
        (h_min * q_max).min(self.template_radius_m)
    }
}

/// Satellite-side data of a sweep: the search field and its spectra.
pub(crate) struct SearchField {
    fft: Fft2,
    spec: Vec<Complex32>,
    energy: Vec<Complex32>,
    /// Ground resolution, metres per pixel.
    pub res: f64,
    /// Field size before padding.
    pub size: usize,
}

impl SearchField {
    /// Prepare the satellite field (`size × size`, square, centred on the search centre).
    pub(crate) fn new(field: &Field, res: f64) -> Self {
        let size = field.width.max(field.height);
        // Valid shifts keep the template inside the field, so no wrap-around needs padding, and
        // any transform size ≥ the field will do: the smallest 2^a·3^b·5^c one (rustfft's fast
        // radices), not the next power of two (a 143-pixel field: 144², not 256², ≈ 3× less work).
        let n = fft_size(size);
        let fft = Fft2::new(n);
        let mut spec = vec![Complex32::new(0.0, 0.0); n * n];
        let mut energy = vec![Complex32::new(0.0, 0.0); n * n];
        for y in 0..field.height {
            for x in 0..field.width {
                let z = field.data[y * field.width + x];
                spec[y * n + x] = z;
                energy[y * n + x] = Complex32::new(z.norm_sqr(), 0.0);
            }
        }
        let mut scratch = Vec::new();
        fft.forward(&mut spec, &mut scratch);
        fft.forward(&mut energy, &mut scratch);
        SearchField {
            fft,
            spec,
            energy,
            res,
            size,
        }
    }
}

/// Relative margin by which [`sweep`]'s score estimate may fall short of the best exact score
/// and still be computed exactly: the estimate and the exact score differ by a few rounding
/// errors (~10⁻¹⁵ relative), so 10⁻⁹ is a wide margin, and a shift within it costs only the
/// exact computation.
const SCORE_SLACK: f64 = 1e-9;

/// A shift of the template inside the search field that [`sweep`] scores.
#[derive(Clone)]
struct Shift {
    /// Its element of the correlation buffer (row-major, side n).
    index: usize,
    /// The satellite field's energy under the template's disk there (> 0) …
    energy: f64,
    /// … and 1 / √ of it.
    inv_sqrt_energy: f64,
    /// The camera offset it stands for, metres (east, north).
    offset: [f64; 2],
}

/// The shifts [`sweep`] scores, in row-major order: those among the first `valid` × `valid`
/// whose disk holds satellite energy and whose camera position lies within `max_offset_m` of
/// the field's centre. Neither depends on the hypothesis, so both are settled here once: the
/// energy is the correlation of the satellite's |z|² with the disk mask (one FFT pair).
fn scored_shifts(
    search: &SearchField,
    r_px: isize,
    side: usize,
    valid: usize,
    centre: f64,
    max_offset_m: f64,
) -> Vec<Shift> {
    let n = search.fft.size();
    let res = search.res;
    let mut scratch = Vec::new();
    let mut mask = vec![Complex32::new(0.0, 0.0); n * n];
    for dy in 0..side {
        for dx in 0..side {
            let (ex, ey) = (dx as isize - r_px, dy as isize - r_px);
            if ex * ex + ey * ey <= r_px * r_px {
                mask[dy * n + dx] = Complex32::new(1.0, 0.0);
            }
        }
    }
    search.fft.forward(&mut mask, &mut scratch);
    let mut local = vec![Complex32::new(0.0, 0.0); n * n];
    for ((l, e), m) in local.iter_mut().zip(&search.energy).zip(&mask) {
        *l = e * m.conj();
    }
    search.fft.inverse(&mut local, &mut scratch);
    let inv_n2 = 1.0 / (n * n) as f64;
    // A hypothesis outside the prior's search disk is not one the prior allows; the corners of
    // the square field would only add chances for a false peak.
    let max_off_px2 = (max_offset_m / res).powi(2);
    let mut shifts = Vec::new();
    for y in 0..valid {
        for x in 0..valid {
            // The inverse transform is unscaled (×n²).
            let e = local[y * n + x].re as f64 * inv_n2;
            if e <= 0.0 {
                continue;
            }
            let cx = x as f64 + r_px as f64 - centre;
            let cy = y as f64 + r_px as f64 - centre;
            if cx * cx + cy * cy > max_off_px2 {
                continue;
            }
            shifts.push(Shift {
                index: y * n + x,
                energy: e,
                inv_sqrt_energy: 1.0 / e.sqrt(),
                offset: [cx * res, -cy * res],
            });
        }
    }
    shifts
}

/// One height of [`sweep`]: what every height shares.
#[derive(Clone)]
struct HeightSweep<'a> {
    search: &'a SearchField,
    nominal: &'a NominalField,
    p: &'a SweepParams,
    /// FFT side.
    n: usize,
    /// Satellite field resolution, m/px.
    res: f64,
    n_yaw: usize,
    /// Template radius and side, px.
    r_px: isize,
    side: usize,
    /// Rows and columns of shifts with the template fully inside.
    valid: usize,
    /// 1 / n².
    inv_n2: f64,
    shifts: Vec<Shift>,
    /// The template's disk, row by row: the columns dx ∈ [lo, hi) inside.
    disk_rows: Vec<(usize, usize)>,
    /// Set when the yaws come in pairs ψ, ψ + π (an even count that divides the turn): the
    /// sweep then transforms once per pair.
    pair: Option<YawPair>,
}

impl<'a> HeightSweep<'a> {
    /// What every height of a sweep over `search` shares; `None` when the template does not fit
    /// inside the search field.
    fn new(search: &'a SearchField, nominal: &'a NominalField, p: &'a SweepParams) -> Option<Self> {
        let n = search.fft.size();
        let res = search.res;
        let n_yaw = (360.0 / p.yaw_step_deg).round().max(1.0) as usize;
        let centre = (search.size as f64 - 1.0) / 2.0;
        // One radius for every height: a correlation over fewer pixels has a higher noise
        // maximum, so height-dependent templates would bias the sweep towards low heights.
        let radius_m = p.effective_template_radius_m(nominal.q_max);
        let r_px = (radius_m / res).floor() as isize;
        let side = (2 * r_px + 1) as usize;
        if side >= search.size {
            return None;
        }
        let valid = search.size - side + 1; // shifts with the template fully inside
        let shifts = scored_shifts(search, r_px, side, valid, centre, p.max_offset_m);
        let disk_rows = (0..side)
            .map(|dy| {
                let ey = dy as isize - r_px;
                let inside = |dx: &usize| {
                    let ex = *dx as isize - r_px;
                    ex * ex + ey * ey <= r_px * r_px
                };
                let lo = (0..side).find(inside).unwrap_or(side);
                let hi = (lo..side).rfind(inside).map_or(lo, |x| x + 1);
                (lo, hi)
            })
            .collect();
        let half_turn = (n_yaw / 2) as f64 * p.yaw_step_deg;
        let pair = (n_yaw % 2 == 0 && (half_turn - 180.0).abs() < 1e-9)
            .then(|| YawPair::new(&search.spec, n, side));
        Some(HeightSweep {
            search,
            nominal,
            p,
            n,
            res,
            n_yaw,
            r_px,
            side,
            valid,
            inv_n2: 1.0 / (n * n) as f64,
            shifts,
            disk_rows,
            pair,
        })
    }

    /// The best shift of every yaw at height `h`.
    ///
    /// On x86-64 CPUs with AVX2 and FMA a copy compiled for them runs (the template's sampling,
    /// the spectra's product and the shifts' scan in wider registers); Rust never fuses a
    /// multiply and an add on its own, so its candidates are the same bits (unit test
    /// `sweep_recovers_yaw_height_and_offset_across_polarity`).
    fn run(&self, h: f64) -> Vec<Candidate> {
        #[cfg(target_arch = "x86_64")]
        if crate::localize::mi::kernel::has_avx2_fma() {
            // SAFETY: the CPU supports the features the function is compiled for (checked above).
            return unsafe { self.run_avx2(h) };
        }
        self.run_plain(h)
    }

    /// [`HeightSweep::run`] compiled for AVX2 + FMA.
    ///
    /// # Safety
    /// The CPU must support AVX2 and FMA.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn run_avx2(&self, h: f64) -> Vec<Candidate> {
        self.run_plain(h)
    }

    /// The body of [`HeightSweep::run`], for the target's baseline features.
    #[inline(always)]
    fn run_plain(&self, h: f64) -> Vec<Candidate> {
        let n = self.n;
        let fft = &self.search.fft;
        let mut scratch = Vec::new();
        let level = self.level(h);
        let mut buf = vec![Complex32::new(0.0, 0.0); n * n];
        let (mut xs, mut ys) = (vec![0.0f32; self.side], vec![0.0f32; self.side]);
        let yaw = |k: usize| (k as f64 * self.p.yaw_step_deg).to_radians();
        // One slot per yaw, filled in any order and read in yaw order.
        let mut best: Vec<Option<Candidate>> = vec![None; self.n_yaw];
        // The template fills the first `side` rows; only the first `valid` rows of the
        // correlation are read (≈ 35 % of the two transforms' row passes saved).
        if let Some(pair) = &self.pair {
            let half = self.n_yaw / 2;
            let mut z = vec![Complex32::new(0.0, 0.0); n * n];
            for k in 0..half {
                let tnorm = self.template(level, h, yaw(k), &mut buf, &mut xs, &mut ys);
                if tnorm <= 0.0 {
                    continue;
                }
                fft.forward_top_rows(&mut buf, &mut scratch, self.side);
                pair.combine(&buf, &mut z);
                fft.inverse_top_rows(&mut z, &mut scratch, self.valid);
                best[k] = self.best_shift(&z, |v| v.re, yaw(k), h, tnorm);
                best[k + half] = self.best_shift(&z, |v| v.im, yaw(k + half), h, tnorm);
            }
        } else {
            for (k, slot) in best.iter_mut().enumerate() {
                let tnorm = self.template(level, h, yaw(k), &mut buf, &mut xs, &mut ys);
                if tnorm <= 0.0 {
                    continue;
                }
                fft.forward_top_rows(&mut buf, &mut scratch, self.side);
                for (b, s) in buf.iter_mut().zip(&self.search.spec) {
                    *b = s * b.conj();
                }
                fft.inverse_top_rows(&mut buf, &mut scratch, self.valid);
                *slot = self.best_shift(&buf, |v| v.re, yaw(k), h, tnorm);
            }
        }
        best.into_iter().flatten().collect()
    }

    /// The pyramid level whose step is closest to (not finer than half) the template step at
    /// height `h`.
    fn level(&self, h: f64) -> usize {
        let (levels, dq) = (&self.nominal.levels, self.nominal.dq);
        let want = self.res / h;
        let mut level = 0;
        while level + 1 < levels.len() && dq * 2f64.powi(level as i32 + 1) <= want * 1.5 {
            level += 1;
        }
        level
    }

    /// Samples the template of yaw `yaw` at height `h` from pyramid level `level` into the
    /// first `side` rows of `buf` (everything else zero) and returns its energy Σ|z|².
    #[inline(always)]
    fn template(
        &self,
        level: usize,
        h: f64,
        yaw: f64,
        buf: &mut [Complex32],
        xs: &mut [f32],
        ys: &mut [f32],
    ) -> f64 {
        let (nominal, n, res, r_px, side) = (self.nominal, self.n, self.res, self.r_px, self.side);
        let f = &nominal.levels[level];
        // A power of two: multiplying by its inverse is exactly dividing by it.
        let inv_scale = 1.0 / 2f64.powi(level as i32);
        // Level-l pixel X averages level-0 pixels [2^l X, 2^l X + 2^l): its centre sits at
        // level-0 coordinate (X + 0.5)·2^l − 0.5.
        let c0 = (nominal.levels[0].width as f64 - 1.0) / 2.0;
        let to_level = |x0: f64| ((x0 + 0.5) * inv_scale - 0.5) as f32;
        let (s, c) = yaw.sin_cos();
        // Image rows run south, so a counter-clockwise map rotation by ψ turns image
        // orientations by −ψ and doubled angles by −2ψ.
        let phase = Complex32::from_polar(1.0, (-2.0 * yaw) as f32);
        buf.iter_mut().for_each(|v| *v = Complex32::new(0.0, 0.0));
        let mut tnorm = 0.0f64;
        for (dy, &(lo, hi)) in self.disk_rows.iter().enumerate() {
            let ey = dy as isize - r_px;
            // Where each template pixel of the row samples the nominal field: the coordinates
            // first (a loop of divisions the compiler can pair), then the samples.
            for dx in lo..hi {
                let ex = dx as isize - r_px;
                // Map offset u (east, north) of this pixel, then q = Rz(−ψ)u / h.
                let (ux, uy) = (ex as f64 * res, -(ey as f64) * res);
                let (qx, qy) = ((c * ux + s * uy) / h, (-s * ux + c * uy) / h);
                xs[dx] = to_level(c0 + qx / nominal.dq);
                ys[dx] = to_level(c0 - qy / nominal.dq);
            }
            let row = &mut buf[dy * n..dy * n + side];
            for dx in lo..hi {
                let z = f.sample(xs[dx], ys[dx]) * phase;
                tnorm += z.norm_sqr() as f64;
                row[dx] = z;
            }
        }
        tnorm
    }

    /// The best shift of one correlation, read from `part` of the unscaled inverse transform
    /// `corr` (×n²), for a template of energy `tnorm`; `None` when no score is finite.
    ///
    /// The score of a shift is a / √(e·tnorm); the first of the highest wins. Its estimate
    /// a·(1/√e)·(1/√tnorm) is within ~10⁻¹⁵ (relative) of it, so a shift whose estimate falls
    /// short of the best score so far by more than `SCORE_SLACK` cannot beat it, and only the
    /// others pay for the exact square root and division: the same winner, from the same exact
    /// scores.
    #[inline(always)]
    fn best_shift(
        &self,
        corr: &[Complex32],
        part: impl Fn(Complex32) -> f32,
        yaw: f64,
        h: f64,
        tnorm: f64,
    ) -> Option<Candidate> {
        let inv_sqrt_t = 1.0 / tnorm.sqrt();
        let mut top = Candidate {
            yaw,
            height: h,
            offset: [0.0; 2],
            score: f64::NEG_INFINITY,
        };
        let mut bar = f64::NEG_INFINITY;
        for sh in &self.shifts {
            let a = part(corr[sh.index]) as f64 * self.inv_n2;
            if a * sh.inv_sqrt_energy * inv_sqrt_t < bar {
                continue;
            }
            let sc = a / (sh.energy * tnorm).sqrt();
            if sc > top.score {
                top.score = sc;
                top.offset = sh.offset;
                bar = sc - SCORE_SLACK * sc.abs() - f64::MIN_POSITIVE;
            }
        }
        top.score.is_finite().then_some(top)
    }
}

/// What lets one forward and one inverse transform serve two yaws ψ and ψ + π.
///
/// Turning the map by π maps every template offset u to −u and leaves the doubled-angle phase
/// as it was, so the template of ψ + π is that of ψ reflected through its centre: with the
/// template in the corner `[0, d]²` of its padding (d = side − 1), T′(x) = T(d − x), and its
/// spectrum is T̂′(k) = φ(k)·T̂(−k) with φ(k) = e^{−2πi(k_x + k_y)d/n}. The sweep reads only
/// the real part of a correlation C = IFFT(Ŝ·conj T̂), which is the inverse of the spectrum's
/// Hermitian part ½(P(k) + conj P(−k)); the Hermitian parts of the two yaws, the second times
/// i, add into one spectrum Z whose inverse holds Re C in its real and Re C′ in its imaginary
/// part. Z(k) = ½Ŝ(k)·conj T̂(k) + ½conj Ŝ(−k)·T̂(−k) + ½i·conj φ(k)·(Ŝ(k)·conj T̂(−k) +
/// conj Ŝ(−k)·T̂(k)): four products per frequency with the factors below, in place of a second
/// template's sampling and forward transform and a second inverse.
#[derive(Debug, Clone)]
struct YawPair {
    /// Side of the spectra.
    n: usize,
    /// ½Ŝ(k).
    s_half: Vec<Complex32>,
    /// ½·conj Ŝ(−k).
    s_neg_half: Vec<Complex32>,
    /// ½i·conj φ(k)·Ŝ(k).
    s_turn: Vec<Complex32>,
    /// ½i·conj φ(k)·conj Ŝ(−k).
    s_neg_turn: Vec<Complex32>,
}

impl YawPair {
    /// The factors for the satellite spectrum `spec` (n × n, transposed like every spectrum
    /// here: the formulas are symmetric in the two axes) and templates of side `side`.
    fn new(spec: &[Complex32], n: usize, side: usize) -> Self {
        let d = side - 1;
        let neg = |a: usize| (n - a) % n;
        let len = n * n;
        let mut p = YawPair {
            n,
            s_half: Vec::with_capacity(len),
            s_neg_half: Vec::with_capacity(len),
            s_turn: Vec::with_capacity(len),
            s_neg_turn: Vec::with_capacity(len),
        };
        for a in 0..n {
            for b in 0..n {
                let s = spec[a * n + b];
                let s_neg = spec[neg(a) * n + neg(b)].conj();
                // i·conj φ(k) = i·e^{2πi(a + b)d/n}, its angle reduced exactly in integers.
                let m = ((a + b) * d) % n;
                let turn = 2.0 * std::f64::consts::PI * m as f64 / n as f64;
                let (sin, cos) = turn.sin_cos();
                let i_conj_phi = Complex32::new(-sin as f32, cos as f32);
                p.s_half.push(s * 0.5);
                p.s_neg_half.push(s_neg * 0.5);
                p.s_turn.push(s * i_conj_phi * 0.5);
                p.s_neg_turn.push(s_neg * i_conj_phi * 0.5);
            }
        }
        p
    }

    /// Z (see the type) of the template spectrum `t` into `z`; both n × n.
    #[inline(always)]
    fn combine(&self, t: &[Complex32], z: &mut [Complex32]) {
        let n = self.n;
        for a in 0..n {
            let row = &t[a * n..(a + 1) * n];
            let row_neg = &t[((n - a) % n) * n..((n - a) % n + 1) * n];
            let range = a * n..(a + 1) * n;
            let (zr, sh, snh, st, snt) = (
                &mut z[range.clone()],
                &self.s_half[range.clone()],
                &self.s_neg_half[range.clone()],
                &self.s_turn[range.clone()],
                &self.s_neg_turn[range],
            );
            for b in 0..n {
                let (x, x_neg) = (row[b], row_neg[(n - b) % n]);
                zr[b] = sh[b] * x.conj() + snh[b] * x_neg + st[b] * x_neg.conj() + snt[b] * x;
            }
        }
    }
}

/// Dense sweep over yaw × height × translation. The search field must cover the search window plus
/// the largest template radius on every side; offsets are relative to its centre.
pub(crate) fn sweep(
    search: &SearchField,
    nominal: &NominalField,
    p: &SweepParams,
) -> Vec<Candidate> {
    sweep_by(search, nominal, p, |job, h| job.run(h))
}

/// [`sweep`] with each height swept by `run` (the dispatched copy, or in a test the plain one).
fn sweep_by(
    search: &SearchField,
    nominal: &NominalField,
    p: &SweepParams,
    run: impl Fn(&HeightSweep<'_>, f64) -> Vec<Candidate> + Sync,
) -> Vec<Candidate> {
    let Some(job) = HeightSweep::new(search, nominal, p) else {
        return Vec::new();
    };
    let per_height: Vec<Vec<Candidate>> = p.heights.par_iter().map(|&h| run(&job, h)).collect();
    let mut all: Vec<Candidate> = per_height.into_iter().flatten().collect();
    // Deterministic order: score, then the hypothesis' own coordinates.
    all.sort_by(|a, b| {
        b.score
            .total_cmp(&a.score)
            .then(a.yaw.total_cmp(&b.yaw))
            .then(a.height.total_cmp(&b.height))
    });
    // Non-maximum suppression: drop candidates near a better one in yaw and position.
    let mut kept: Vec<Candidate> = Vec::new();
    for c in all {
        let near = kept.iter().any(|k| {
            let dyaw = crate::pose::angle_difference(c.yaw, k.yaw).abs();
            let dpos =
                ((c.offset[0] - k.offset[0]).powi(2) + (c.offset[1] - k.offset[1]).powi(2)).sqrt();
            dyaw < 10f64.to_radians() && dpos < 2.0
        });
        if !near {
            kept.push(c);
            if kept.len() == p.top_k {
                break;
            }
        }
    }
    kept
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// [`magnitude`] is glibc's `hypotf` to the bit (what `Complex32::norm` calls), on
    /// magnitudes from sub-normal to huge and on Sobel-like integers.
    #[test]
    #[cfg(all(target_arch = "x86_64", target_os = "linux", target_env = "gnu"))]
    fn magnitude_is_the_library_s_hypot() {
        let mut v = 0x2545_f491_u32;
        for k in 0..200_000u32 {
            v ^= v << 13;
            v ^= v >> 17;
            v ^= v << 5;
            let (a, b) = if k % 2 == 0 {
                (
                    f32::from_bits(v & 0x7f7f_ffff),
                    f32::from_bits(v.rotate_left(11) & 0xff7f_ffff),
                )
            } else {
                (
                    (v % 2041) as f32 - 1020.0,
                    (v.rotate_left(7) % 2041) as f32 - 1020.0,
                )
            };
            let z = Complex32::new(a, b);
            assert_eq!(magnitude(z).to_bits(), z.norm().to_bits(), "{a:e} {b:e}");
        }
    }

    /// The pair's one spectrum Z inverts to the real parts of two correlations, the template's
    /// and its reflection through its centre's, checked against the sums themselves (n = 12, a
    /// 5-pixel template, every valid shift).
    #[test]
    fn a_yaw_pair_inverts_to_both_real_correlations() {
        let (n, side) = (12usize, 5usize);
        let valid = n - side + 1;
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut cplx = || Complex32::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
        let sat: Vec<Complex32> = (0..n * n).map(|_| cplx()).collect();
        let mut t = vec![Complex32::new(0.0, 0.0); n * n];
        for y in 0..side {
            for x in 0..side {
                t[y * n + x] = cplx();
            }
        }
        let fft = Fft2::new(n);
        let mut scratch = Vec::new();
        let mut spec = sat.clone();
        fft.forward(&mut spec, &mut scratch);
        let pair = YawPair::new(&spec, n, side);
        let mut t_spec = t.clone();
        fft.forward(&mut t_spec, &mut scratch);
        let mut z = vec![Complex32::new(0.0, 0.0); n * n];
        pair.combine(&t_spec, &mut z);
        fft.inverse(&mut z, &mut scratch);
        let d = side - 1;
        for sy in 0..valid {
            for sx in 0..valid {
                let (mut c, mut c_turned) = (0.0f64, 0.0f64);
                for y in 0..side {
                    for x in 0..side {
                        let s = sat[(sy + y) * n + sx + x];
                        c += (s * t[y * n + x].conj()).re as f64;
                        c_turned += (s * t[(d - y) * n + d - x].conj()).re as f64;
                    }
                }
                let got = z[sy * n + sx] / (n * n) as f32;
                assert!(
                    (got.re as f64 - c).abs() < 1e-4,
                    "({sx}, {sy}): {got} vs {c}"
                );
                assert!(
                    (got.im as f64 - c_turned).abs() < 1e-4,
                    "({sx}, {sy}): {got} vs {c_turned}"
                );
            }
        }
    }

    /// A procedural "ground": random bright bars and blobs on a textured background.
    fn ground(seed: u64) -> impl Fn(f64, f64) -> f32 {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let bars: Vec<(f64, f64, f64, f64, f64)> = (0..60)
            .map(|_| {
                (
                    rng.random_range(-40.0..40.0),
                    rng.random_range(-40.0..40.0),
                    rng.random_range(0.0..std::f64::consts::PI),
                    rng.random_range(1.0..8.0),
                    rng.random_range(0.15..0.6),
                )
            })
            .collect();
        move |x, y| {
            // Non-periodic background texture (hashed 0.5 m cells), like asphalt grain.
            let (cx, cy) = ((x * 2.0).floor() as i64, (y * 2.0).floor() as i64);
            let hash = (cx.wrapping_mul(73_856_093) ^ cy.wrapping_mul(19_349_663)).rem_euclid(1000);
            let mut v = 0.3 + 0.05 * (hash as f32 / 1000.0);
            for &(bx, by, a, len, wid) in &bars {
                let (dx, dy) = (x - bx, y - by);
                let along = dx * a.cos() + dy * a.sin();
                let across = -dx * a.sin() + dy * a.cos();
                if along.abs() < len && across.abs() < wid {
                    v = 0.9;
                }
            }
            v
        }
    }

    #[test]
    fn blocked_transpose_equals_the_element_loop() {
        // Sides below, at, between and above the block size.
        for n in [1usize, 5, 32, 33, 64, 100] {
            let orig: Vec<Complex32> = (0..n * n)
                .map(|i| Complex32::new(i as f32, -(i as f32) * 0.5))
                .collect();
            let mut buf = orig.clone();
            transpose(&mut buf, n);
            for y in 0..n {
                for x in 0..n {
                    assert_eq!(buf[x * n + y], orig[y * n + x], "n {n} at ({x}, {y})");
                }
            }
        }
    }

    #[test]
    fn pruned_transpose_gives_the_wanted_rows_of_the_full_one() {
        for n in [5usize, 33, 64, 100] {
            for (nonzero, keep) in [(n, n), (1, n), (n / 3, n), (n, n / 2), (n / 3, 2 * n / 3)] {
                let mut orig: Vec<Complex32> = (0..n * n)
                    .map(|i| Complex32::new(i as f32 + 1.0, -(i as f32) * 0.5))
                    .collect();
                orig[nonzero * n..].fill(Complex32::new(0.0, 0.0));
                let mut full = orig.clone();
                transpose(&mut full, n);
                let mut pruned = orig.clone();
                transpose_pruned(&mut pruned, n, nonzero, keep);
                assert!(
                    pruned[..keep * n] == full[..keep * n],
                    "n {n}, nonzero {nonzero}, keep {keep}"
                );
            }
        }
    }

    #[test]
    fn fft_sizes_are_the_smallest_5_smooth_ones() {
        let got: Vec<usize> = [0, 1, 7, 11, 13, 143, 185, 256, 257]
            .iter()
            .map(|&s| fft_size(s))
            .collect();
        assert_eq!(got, vec![1, 1, 8, 12, 15, 144, 192, 256, 270]);
    }

    #[test]
    fn pruned_transforms_equal_the_full_ones_bit_for_bit() {
        for (n, rows) in [(8usize, 3usize), (64, 17), (128, 128), (128, 1)] {
            let fft = Fft2::new(n);
            let mut scratch = Vec::new();
            // A template in the first `rows` rows, zeros below (as the sweep pads it).
            let mut a = vec![Complex32::new(0.0, 0.0); n * n];
            for (i, v) in a.iter_mut().take(rows * n).enumerate() {
                *v = Complex32::new(((i * 37) % 101) as f32 - 50.0, ((i * 11) % 13) as f32);
            }
            let orig = a.clone();
            let mut b = a.clone();
            fft.forward(&mut a, &mut scratch);
            fft.forward_top_rows(&mut b, &mut scratch, rows);
            assert!(a == b, "forward, n {n}, rows {rows}");
            // Back: the first `rows` rows of the pruned inverse equal the full inverse's.
            let mut c = a.clone();
            fft.inverse(&mut a, &mut scratch);
            fft.inverse_top_rows(&mut c, &mut scratch, rows);
            assert!(
                a[..rows * n] == c[..rows * n],
                "inverse, n {n}, rows {rows}"
            );
            // And the round trip gives the template back (×n²).
            let scale = 1.0 / (n * n) as f32;
            for (i, (got, want)) in c.iter().zip(&orig).take(rows * n).enumerate() {
                assert!(
                    (got * scale - want).norm() < 1e-2,
                    "round trip, n {n}, at {i}"
                );
            }
        }
    }

    #[test]
    fn sweep_recovers_yaw_height_and_offset_across_polarity() {
        let g = ground(3);
        let (true_yaw, true_h, true_off) = (137f64.to_radians(), 8.0, [3.2, -4.4]);
        // Satellite field at 0.4 m/px over ±34 m around the search centre.
        let res = 0.4;
        let size = 171;
        let c = (size as f64 - 1.0) / 2.0;
        let mut sat = GrayF32::new(size, size);
        for y in 0..size {
            for x in 0..size {
                // Inverted polarity, as paint vs shadowed asphalt can be across modalities.
                sat.data[y * size + x] = 1.0 - g((x as f64 - c) * res, (c - y as f64) * res);
            }
        }
        let search = SearchField::new(&orientation_field(&sat, None), res);
        // Nominal BEV seen by the true camera: B(q) = ground(off + h·Rz(ψ)q).
        let (dq, q_max) = (0.01, 2.0);
        let nb = 2 * (q_max / dq) as usize + 1;
        let bc = (nb as f64 - 1.0) / 2.0;
        let mut b = GrayF32::new(nb, nb);
        let (s, co) = true_yaw.sin_cos();
        for y in 0..nb {
            for x in 0..nb {
                let (qx, qy) = ((x as f64 - bc) * dq, (bc - y as f64) * dq);
                let (ux, uy) = (true_h * (co * qx - s * qy), true_h * (s * qx + co * qy));
                b.data[y * nb + x] = g(true_off[0] + ux, true_off[1] + uy);
            }
        }
        let mut levels = vec![orientation_field(&b, None)];
        for _ in 0..4 {
            let next = levels.last().unwrap().downsample2();
            levels.push(next);
        }
        let nominal = NominalField { levels, dq, q_max };
        let params = SweepParams {
            yaw_step_deg: 3.0,
            heights: (0..10).map(|i| 5.5 * 1.06f64.powi(i)).collect(),
            template_radius_m: 14.0,
            top_k: 3,
            max_offset_m: f64::INFINITY,
        };
        let best = sweep(&search, &nominal, &params)[0];
        let dyaw = (best.yaw - true_yaw).abs().to_degrees();
        let dpos = ((best.offset[0] - true_off[0]).powi(2)
            + (best.offset[1] - true_off[1]).powi(2))
        .sqrt();
        assert!(
            dyaw <= 3.0 && dpos <= 0.8 && (best.height / true_h - 1.0).abs() < 0.07,
            "{best:?}"
        );
        // The dispatched copy (AVX2 where this CPU has it) finds every height's and yaw's best
        // shift with the same score, to the bit, as the plain loop.
        let every = SweepParams {
            top_k: usize::MAX,
            ..params
        };
        let plain = sweep_by(&search, &nominal, &every, |j, h| j.run_plain(h));
        assert!(plain.len() > 20, "{} candidates", plain.len());
        assert_eq!(plain, sweep_by(&search, &nominal, &every, |j, h| j.run(h)));
        // Yaws in pairs ψ, ψ + π (one transform pair for two yaws) give every candidate of
        // one yaw at a time, with scores equal to single precision's rounding.
        let single = sweep_by(&search, &nominal, &every, |j, h| {
            assert!(j.pair.is_some(), "3° steps pair their yaws");
            HeightSweep {
                pair: None,
                ..j.clone()
            }
            .run_plain(h)
        });
        assert_eq!(plain.len(), single.len());
        for (a, b) in plain.iter().zip(&single) {
            assert_eq!((a.yaw, a.height, a.offset), (b.yaw, b.height, b.offset));
            assert!((a.score - b.score).abs() < 1e-5, "{a:?} vs {b:?}");
        }
    }
}
