//! Counter-based noise: hash-derived lattice noise and per-sample random numbers.
//!
//! Every texture, speckle and sensor-noise value is a pure function of (seed, position/index), not
//! a draw from a sequential RNG, so rows can be rendered in parallel in any order and the output is
//! still bit-identical for a seed. (Sequential choices — layout, object placement — use
//! `ChaCha8Rng`.)

/// SplitMix64 finaliser: a fast, well-mixed 64-bit hash.
#[inline]
pub(crate) fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Hash of a seed and two integer coordinates.
#[inline]
pub(crate) fn hash3(seed: u64, a: i64, b: i64) -> u64 {
    mix64(seed ^ mix64((a as u64).wrapping_mul(0x2545_F491_4F6C_DD1D) ^ mix64(b as u64)))
}

/// Uniform in [0, 1) from a hash.
#[inline]
pub(crate) fn unit(h: u64) -> f64 {
    (h >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// Standard normal from two hashes (Box–Muller).
#[inline]
pub(crate) fn gauss(h: u64) -> f64 {
    let u1 = unit(h).max(1e-300);
    let u2 = unit(mix64(h ^ 0xA5A5_A5A5_5A5A_5A5A));
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// A deterministic 2-D noise field (value noise with quintic fade), values in about [−1, 1].
#[derive(Debug, Clone, Copy)]
pub(crate) struct Field {
    seed: u64,
    /// Feature size, metres (lattice spacing).
    scale: f64,
}

impl Field {
    /// A field with lattice spacing `scale` metres.
    pub(crate) fn new(seed: u64, scale: f64) -> Self {
        Field { seed, scale }
    }

    #[inline]
    fn lattice(&self, i: i64, j: i64) -> f64 {
        unit(hash3(self.seed, i, j)) * 2.0 - 1.0
    }

    /// Value at (x, y).
    #[inline]
    pub(crate) fn at(&self, x: f64, y: f64) -> f64 {
        let (u, v) = (x / self.scale, y / self.scale);
        let (fi, fj) = (u.floor(), v.floor());
        let (i, j) = (fi as i64, fj as i64);
        let (tx, ty) = (fade(u - fi), fade(v - fj));
        let a = self.lattice(i, j);
        let b = self.lattice(i + 1, j);
        let c = self.lattice(i, j + 1);
        let d = self.lattice(i + 1, j + 1);
        let ab = a + (b - a) * tx;
        let cd = c + (d - c) * tx;
        ab + (cd - ab) * ty
    }

    /// Fractal sum of `octaves` octaves (each half the size, half the amplitude), about [−1, 1].
    pub(crate) fn fbm(&self, x: f64, y: f64, octaves: u32) -> f64 {
        let (mut sum, mut amp, mut norm) = (0.0, 1.0, 0.0);
        let mut f = *self;
        for o in 0..octaves {
            sum += amp * f.at(x, y);
            norm += amp;
            amp *= 0.5;
            f = Field::new(mix64(self.seed.wrapping_add(o as u64 + 1)), f.scale * 0.5);
        }
        sum / norm
    }
}

#[inline]
fn fade(t: f64) -> f64 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

/// Smooth step from 0 at `e0` to 1 at `e1`.
#[inline]
pub(crate) fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn field_is_continuous_and_bounded() {
        let f = Field::new(7, 2.0);
        let mut prev = f.at(0.0, 0.3);
        for i in 1..2000 {
            let x = i as f64 * 0.01;
            let v = f.at(x, 0.3);
            assert!((-1.0..=1.0).contains(&v));
            assert!((v - prev).abs() < 0.05, "jump at {x}");
            prev = v;
        }
    }

    #[test]
    fn gauss_has_unit_variance() {
        let n = 20000;
        let (mut s, mut s2) = (0.0, 0.0);
        for i in 0..n {
            let g = gauss(mix64(i));
            s += g;
            s2 += g * g;
        }
        let mean = s / n as f64;
        let var = s2 / n as f64 - mean * mean;
        assert!(
            mean.abs() < 0.03 && (var - 1.0).abs() < 0.05,
            "{mean} {var}"
        );
    }
}
