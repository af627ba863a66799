//! Image operations the core's stages share (the calibration's corner detector, the simulator's
//! renderer): pure functions over row-major planes.

use rayon::prelude::*;

/// Separable Gaussian blur of a row-major plane (σ in pixels; ≤ 0 does nothing).
pub fn gaussian_blur(plane: &mut [f32], w: usize, h: usize, sigma: f64) {
    if sigma <= 0.0 {
        return;
    }
    let r = (3.0 * sigma).ceil() as isize;
    let mut k: Vec<f32> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp() as f32)
        .collect();
    let sum: f32 = k.iter().sum();
    k.iter_mut().for_each(|v| *v /= sum);
    let clampi = |i: isize, n: usize| i.clamp(0, n as isize - 1) as usize;
    let src = plane.to_vec();
    plane.par_chunks_mut(w).enumerate().for_each(|(row, out)| {
        let line = &src[row * w..(row + 1) * w];
        for (col, o) in out.iter_mut().enumerate() {
            *o = k
                .iter()
                .enumerate()
                .map(|(j, kv)| kv * line[clampi(col as isize + j as isize - r, w)])
                .sum();
        }
    });
    let src = plane.to_vec();
    plane.par_chunks_mut(w).enumerate().for_each(|(row, out)| {
        for (col, o) in out.iter_mut().enumerate() {
            *o = k
                .iter()
                .enumerate()
                .map(|(j, kv)| kv * src[clampi(row as isize + j as isize - r, h) * w + col])
                .sum();
        }
    });
}
