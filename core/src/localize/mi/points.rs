//! Ground points (map CRS, f64) and their hot-loop form (origin-shifted f32, structure of arrays).

use crate::localize::error::LocalizeError;
use rayon::prelude::*;

/// One LiDAR ground point: map-CRS coordinates (f64 metres) and reflectivity (0–255). The same
/// type the tile cache's `crate::map::ground_points` produces.
pub use crate::map::GroundPoint;

/// Check a point set for the refinement: non-empty and all coordinates finite. `what` names the
/// source (file or tile) in the error.
pub fn validate(points: &[GroundPoint], what: &str) -> std::result::Result<(), LocalizeError> {
    if points.is_empty() {
        return Err(LocalizeError::NoPoints {
            what: what.to_string(),
        });
    }
    if let Some((i, p)) = points
        .iter()
        .enumerate()
        .find(|(_, p)| !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()))
    {
        return Err(LocalizeError::NonFinitePoint {
            what: what.to_string(),
            index: i,
            x: p.x,
            y: p.y,
            z: p.z,
        });
    }
    Ok(())
}

/// Points in the hot-loop form: coordinates relative to `origin` as f32 (the refinement works
/// within ~100 m of the origin, where f32 resolves 8 µm), structure of arrays so the projection loop
/// vectorises, plus the reflectivity already mapped to its histogram bin.
#[derive(Debug, Clone, Default)]
pub struct PreparedPoints {
    /// x − origin.x.
    pub x: Vec<f32>,
    /// y − origin.y.
    pub y: Vec<f32>,
    /// z − origin.z.
    pub z: Vec<f32>,
    /// Reflectivity histogram bin (row of the joint histogram).
    pub bin: Vec<u8>,
}

impl PreparedPoints {
    /// Number of points.
    pub(crate) fn len(&self) -> usize {
        self.x.len()
    }

    /// Whether there are no points.
    pub(crate) fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Build from map points: subtract `origin`, map reflectivity through `lut` (256 entries →
    /// bin), and order the points along a Morton (Z-order) curve so that consecutive points project
    /// to nearby pixels (cache locality in the image gather) and a strided subsample is spatially
    /// uniform. Ordering makes the result independent of the input order.
    pub fn new(points: &[GroundPoint], origin: [f64; 3], lut: &[u8; 256]) -> Self {
        Self::gather(points, &morton_order(points), origin, lut)
    }

    /// [`PreparedPoints::new`] with the points' Morton order already computed
    /// ([`morton_order`] of the same `points`): evaluators built on one point set share it.
    pub(crate) fn gather(
        points: &[GroundPoint],
        order: &[usize],
        origin: [f64; 3],
        lut: &[u8; 256],
    ) -> Self {
        let n = order.len();
        let mut out = PreparedPoints {
            x: vec![0.0; n],
            y: vec![0.0; n],
            z: vec![0.0; n],
            bin: vec![0; n],
        };
        // In parallel: each element is computed on its own, so the result does not depend on the
        // split.
        const BLOCK: usize = 4096;
        out.x
            .par_chunks_mut(BLOCK)
            .zip(out.y.par_chunks_mut(BLOCK))
            .zip(out.z.par_chunks_mut(BLOCK))
            .zip(out.bin.par_chunks_mut(BLOCK))
            .zip(order.par_chunks(BLOCK))
            .for_each(|((((xs, ys), zs), bins), block)| {
                for (j, &i) in block.iter().enumerate() {
                    let p = &points[i];
                    xs[j] = (p.x - origin[0]) as f32;
                    ys[j] = (p.y - origin[1]) as f32;
                    zs[j] = (p.z - origin[2]) as f32;
                    bins[j] = lut[p.reflectivity as usize];
                }
            });
        out
    }

    /// Every `stride`-th point (stride ≥ 1): along the Morton order this is a spatially uniform
    /// subsample, used at the coarse search levels.
    pub(crate) fn subsample(&self, stride: usize) -> Self {
        let s = stride.max(1);
        PreparedPoints {
            x: self.x.iter().step_by(s).copied().collect(),
            y: self.y.iter().step_by(s).copied().collect(),
            z: self.z.iter().step_by(s).copied().collect(),
            bin: self.bin.iter().step_by(s).copied().collect(),
        }
    }

    /// The points `a..b` (along the Morton order: a compact patch of ground).
    pub(crate) fn range(&self, a: usize, b: usize) -> Self {
        let (a, b) = (a.min(self.len()), b.min(self.len()));
        PreparedPoints {
            x: self.x[a..b.max(a)].to_vec(),
            y: self.y[a..b.max(a)].to_vec(),
            z: self.z[a..b.max(a)].to_vec(),
            bin: self.bin[a..b.max(a)].to_vec(),
        }
    }

    /// The points whose flag is set.
    pub(crate) fn select(&self, keep: &[bool]) -> Self {
        // Keeping every point is common (a fixed set that every lattice pose sees whole, the
        // naive estimator): one copy per array instead of a push per point.
        if keep.len() >= self.len() && keep[..self.len()].iter().all(|&k| k) {
            return self.clone();
        }
        let mut out = PreparedPoints::default();
        for (i, &k) in keep.iter().enumerate().take(self.len()) {
            if k {
                out.x.push(self.x[i]);
                out.y.push(self.y[i]);
                out.z.push(self.z[i]);
                out.bin.push(self.bin[i]);
            }
        }
        out
    }
}

/// The indices of `points` along a Morton (Z-order) curve over their bounding square, equal
/// cells in index order: the order [`PreparedPoints::new`] lays the points out in. It depends on
/// the points' x and y alone (not on an origin or a bin table), so one computation serves every
/// evaluator of a refinement.
pub(crate) fn morton_order(points: &[GroundPoint]) -> Vec<usize> {
    if points.is_empty() {
        return Vec::new();
    }
    // Bounds and keys on the thread pool: min/max and each key are exact, so neither depends on
    // the split.
    let (x0, y0, x1, y1) = points
        .par_iter()
        .fold(
            || (f64::MAX, f64::MAX, f64::MIN, f64::MIN),
            |(x0, y0, x1, y1), p| (x0.min(p.x), y0.min(p.y), x1.max(p.x), y1.max(p.y)),
        )
        .reduce(
            || (f64::MAX, f64::MAX, f64::MIN, f64::MIN),
            |a, b| (a.0.min(b.0), a.1.min(b.1), a.2.max(b.2), a.3.max(b.3)),
        );
    let span = (x1 - x0).max(y1 - y0).max(1e-9);
    // 20 bits per axis: 1 µm cells on a 1 km tile, far below any point spacing.
    const MORTON_BITS: u32 = 20;
    let scale = ((1u64 << MORTON_BITS) - 1) as f64 / span;
    let keyed: Vec<(u64, usize)> = points
        .par_iter()
        .enumerate()
        .map(|(i, p)| {
            let ix = ((p.x - x0) * scale) as u64;
            let iy = ((p.y - y0) * scale) as u64;
            (morton2(ix, iy), i)
        })
        .collect();
    radix_sort_by_key(keyed)
        .into_iter()
        .map(|(_, i)| i)
        .collect()
}

/// `items` (built in index order) sorted by key, equal keys in index order: the order of sorting
/// the (key, index) pairs. A least-significant-digit radix sort over the keys' used bits (40 for
/// Morton codes): a few linear passes where a comparison sort of 10⁵–10⁶ points took
/// log₂ n ≈ 18 rounds of comparisons; every pass is stable, so equal keys keep the input's
/// (index) order.
fn radix_sort_by_key(mut items: Vec<(u64, usize)>) -> Vec<(u64, usize)> {
    const DIGIT: u32 = 11;
    let used = items.iter().fold(0u64, |a, &(k, _)| a | k);
    let bits = u64::BITS - used.leading_zeros();
    let mut tmp = vec![(0u64, 0usize); items.len()];
    let mut shift = 0;
    while shift < bits {
        let digit = |k: u64| ((k >> shift) & ((1 << DIGIT) - 1)) as usize;
        let mut start = vec![0usize; (1 << DIGIT) + 1];
        for &(k, _) in &items {
            start[digit(k) + 1] += 1;
        }
        for d in 1..start.len() {
            start[d] += start[d - 1];
        }
        for &item in &items {
            let d = digit(item.0);
            tmp[start[d]] = item;
            start[d] += 1;
        }
        std::mem::swap(&mut items, &mut tmp);
        shift += DIGIT;
    }
    items
}

/// Interleave the low 20 bits of `x` and `y`.
fn morton2(x: u64, y: u64) -> u64 {
    fn spread(mut v: u64) -> u64 {
        v &= 0x0000_0000_ffff_ffff;
        v = (v | (v << 16)) & 0x0000_ffff_0000_ffff;
        v = (v | (v << 8)) & 0x00ff_00ff_00ff_00ff;
        v = (v | (v << 4)) & 0x0f0f_0f0f_0f0f_0f0f;
        v = (v | (v << 2)) & 0x3333_3333_3333_3333;
        v = (v | (v << 1)) & 0x5555_5555_5555_5555;
        v
    }
    spread(x) | (spread(y) << 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn validate_rejects_empty_and_nan() {
        assert!(validate(&[], "t").is_err());
        let p = GroundPoint {
            x: 1.0,
            y: f64::NAN,
            z: 0.0,
            reflectivity: 3,
        };
        let e = validate(&[p], "pts.csv").unwrap_err().to_string();
        assert!(e.contains("pts.csv") && e.contains("point 0"), "{e}");
    }

    /// The radix sort orders as sorting the (key, index) pairs does: duplicate keys, keys of
    /// every width up to 64 bits, empty and one-element inputs.
    #[test]
    fn radix_sort_orders_as_the_pair_sort() {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        for (n, bits) in [
            (0, 40),
            (1, 40),
            (1000, 40),
            (5000, 7),
            (3000, 64),
            (2000, 1),
        ] {
            let items: Vec<(u64, usize)> = (0..n).map(|i| (next() >> (64 - bits), i)).collect();
            let mut want = items.clone();
            want.sort_unstable();
            assert_eq!(radix_sort_by_key(items), want, "{n} keys of {bits} bits");
        }
    }

    #[test]
    fn prepared_points_are_order_independent_and_shifted() {
        let mut lut = [0u8; 256];
        for (i, l) in lut.iter_mut().enumerate() {
            *l = (i / 8) as u8;
        }
        let pts: Vec<GroundPoint> = (0..50)
            .map(|i| GroundPoint {
                x: 500_000.0 + (i % 7) as f64,
                y: 4_000_000.0 + (i / 7) as f64 * 0.5,
                z: 200.0,
                reflectivity: (i * 5) as u8,
            })
            .collect();
        let mut rev = pts.clone();
        rev.reverse();
        let o = [500_003.0, 4_000_001.0, 206.0];
        let a = PreparedPoints::new(&pts, o, &lut);
        let b = PreparedPoints::new(&rev, o, &lut);
        assert_eq!(a.x, b.x);
        assert_eq!(a.bin, b.bin);
        assert_eq!(a.len(), 50);
        assert!(a.z.iter().all(|&z| z == -6.0));
        assert!(a.x.iter().all(|&x| (-3.0..=3.0).contains(&x)));
        assert_eq!(a.subsample(4).len(), 13);
        assert_eq!(morton2(1, 0), 1);
        assert_eq!(morton2(0, 1), 2);
        assert_eq!(morton2(3, 3), 15);
    }
}
