//! Per-pixel temporal median of a short burst of frames: moving traffic occupies a pixel in a
//! minority of frames, so the median shows the empty road the map was made of.
//!
//! For the burst sizes the node uses (3–15 frames) a sorting network applied lane-wise to a
//! block of pixels is fastest: each compare-exchange is an element-wise `min`/`max` of two
//! byte arrays, which the compiler turns into SIMD, and rows run in parallel (rayon). Longer
//! bursts fall back to per-pixel selection (`select_nth_unstable`).

use image::GrayImage;
use rayon::prelude::*;

use crate::error::{Error, Result};

/// Pixels processed together; a multiple of the widest SIMD register (32 bytes on AVX2).
const LANES: usize = 64;
/// Longest burst handled by the sorting network (odd-even transposition: n(n−1)/2
/// compare-exchanges); beyond it per-pixel selection is cheaper.
const NETWORK_MAX: usize = 16;

/// Per-pixel median of `frames` (all the same size). For an even count this is the lower of the
/// two middle values — a value some frame actually saw, never a blend of a car and the road.
pub fn temporal_median(frames: &[GrayImage]) -> Result<GrayImage> {
    let first = frames
        .first()
        .ok_or_else(|| Error::Invalid("temporal median of zero frames".into()))?;
    let (w, h) = first.dimensions();
    if let Some((i, f)) = frames
        .iter()
        .enumerate()
        .find(|(_, f)| f.dimensions() != (w, h))
    {
        return Err(Error::stage(
            crate::stage::StageName::Capture,
            format!(
                "frame {i} is {}x{}, frame 0 is {w}x{h}: cannot take a temporal median",
                f.width(),
                f.height()
            ),
        ));
    }
    let mut out = GrayImage::new(w, h);
    let w = w as usize;
    if w == 0 || h == 0 {
        return Ok(out);
    }
    let planes: Vec<&[u8]> = frames.iter().map(|f| f.as_raw().as_slice()).collect();
    out.par_chunks_exact_mut(w)
        .enumerate()
        .for_each(|(y, dst)| {
            let rows: Vec<&[u8]> = planes.iter().map(|p| &p[y * w..(y + 1) * w]).collect();
            median_row(&rows, dst);
        });
    Ok(out)
}

/// Median of `rows` element-wise into `dst`.
fn median_row(rows: &[&[u8]], dst: &mut [u8]) {
    let n = rows.len();
    let mid = (n - 1) / 2;
    if n > NETWORK_MAX {
        let mut v = vec![0u8; n];
        for (x, d) in dst.iter_mut().enumerate() {
            for (s, r) in v.iter_mut().zip(rows) {
                *s = r[x];
            }
            *d = *v.select_nth_unstable(mid).1;
        }
        return;
    }
    let mut block = [[0u8; LANES]; NETWORK_MAX];
    for (start, d) in (0..dst.len()).step_by(LANES).zip(dst.chunks_mut(LANES)) {
        let len = d.len();
        for (b, r) in block.iter_mut().zip(rows) {
            b[..len].copy_from_slice(&r[start..start + len]);
        }
        // Odd-even transposition sort: n rounds of disjoint neighbour compare-exchanges sort
        // n items; every comparator works on all LANES pixels at once.
        for round in 0..n {
            let mut i = round % 2;
            while i + 1 < n {
                let (lo, hi) = block.split_at_mut(i + 1);
                compare_exchange(&mut lo[i], &mut hi[0]);
                i += 2;
            }
        }
        d.copy_from_slice(&block[mid][..len]);
    }
}

/// Lane-wise `(a, b) ← (min, max)`.
#[inline(always)]
fn compare_exchange(a: &mut [u8; LANES], b: &mut [u8; LANES]) {
    for (x, y) in a.iter_mut().zip(b.iter_mut()) {
        let (lo, hi) = ((*x).min(*y), (*x).max(*y));
        *x = lo;
        *y = hi;
    }
}

/// The obvious implementation — gather each pixel's values, sort, take the middle — kept as the
/// baseline the benchmark measures [`temporal_median`] against, and as the tests' reference.
pub fn temporal_median_naive(frames: &[GrayImage]) -> Result<GrayImage> {
    let first = frames
        .first()
        .ok_or_else(|| Error::Invalid("temporal median of zero frames".into()))?;
    let (w, h) = first.dimensions();
    if frames.iter().any(|f| f.dimensions() != (w, h)) {
        return Err(Error::stage(
            crate::stage::StageName::Capture,
            "frames differ in size",
        ));
    }
    let mid = (frames.len() - 1) / 2;
    Ok(GrayImage::from_fn(w, h, |x, y| {
        let mut v: Vec<u8> = frames.iter().map(|f| f.get_pixel(x, y)[0]).collect();
        v.sort_unstable();
        image::Luma([v[mid]])
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_frames(n: usize, w: u32, h: u32, seed: u64) -> Vec<GrayImage> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .map(|_| GrayImage::from_fn(w, h, |_, _| image::Luma([rng.random()])))
            .collect()
    }

    #[test]
    fn matches_sort_reference_for_every_burst_length() {
        // Widths that are not multiples of LANES exercise the tail block; n > NETWORK_MAX the
        // selection fallback.
        for n in 1..=NETWORK_MAX + 4 {
            let frames = random_frames(n, 131, 7, n as u64);
            let fast = temporal_median(&frames).unwrap();
            let naive = temporal_median_naive(&frames).unwrap();
            assert_eq!(fast, naive, "n = {n}");
        }
    }

    #[test]
    fn removes_a_moving_object() {
        // A bright "car" crosses a dark textured road: in each of 5 frames it covers a different
        // place; the median must be the bare road everywhere.
        let road = GrayImage::from_fn(100, 20, |x, y| image::Luma([(x % 17 + y % 5) as u8 * 3]));
        let frames: Vec<GrayImage> = (0..5)
            .map(|k| {
                let mut f = road.clone();
                for y in 5..15 {
                    for x in k * 20..k * 20 + 15 {
                        f.put_pixel(x, y, image::Luma([250]));
                    }
                }
                f
            })
            .collect();
        assert_eq!(temporal_median(&frames).unwrap(), road);
    }

    #[test]
    fn even_count_takes_lower_middle() {
        let frames: Vec<GrayImage> = [10u8, 40, 20, 30]
            .iter()
            .map(|&v| GrayImage::from_pixel(3, 2, image::Luma([v])))
            .collect();
        let m = temporal_median(&frames).unwrap();
        assert!(m.pixels().all(|p| p[0] == 20));
    }

    #[test]
    fn size_mismatch_and_empty_are_errors() {
        let mut frames = random_frames(3, 8, 8, 1);
        frames.push(GrayImage::new(8, 9));
        let e = temporal_median(&frames).unwrap_err().to_string();
        assert!(e.contains("frame 3 is 8x9"), "{e}");
        assert!(temporal_median(&[]).is_err());
    }
}
