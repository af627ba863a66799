//! Capture benchmarks: temporal median of 5 frames of 5 MP (2592×1944, a common 5 MP sensor),
//! the sorting-network implementation against the naive baseline (gather + sort per pixel) in
//! the same run. `cargo bench --bench capture`; figures in docs/benchmarks.md ("Capture").

use criterion::{criterion_group, criterion_main, Criterion};
use image::GrayImage;
use infraloc::capture::median::{temporal_median, temporal_median_naive};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;
use std::time::Duration;

const WIDTH: u32 = 2592;
const HEIGHT: u32 = 1944;
const FRAMES: usize = 5;

/// A textured road with noise, plus a bright block at a different place in each frame.
fn frames() -> Vec<GrayImage> {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    (0..FRAMES)
        .map(|k| {
            GrayImage::from_fn(WIDTH, HEIGHT, |x, y| {
                let car = (x / 400) as usize == k && (800..1100).contains(&y);
                let v = if car {
                    240
                } else {
                    ((x ^ y) % 97) as u8 + rng.random_range(0..8)
                };
                image::Luma([v])
            })
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let frames = frames();
    let mut g = c.benchmark_group("temporal_median_5x5MP");
    g.sample_size(10).measurement_time(Duration::from_secs(8));
    g.bench_function("network_rayon", |b| {
        b.iter(|| temporal_median(black_box(&frames)).unwrap())
    });
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    g.bench_function("network_1_thread", |b| {
        b.iter(|| one.install(|| temporal_median(black_box(&frames)).unwrap()))
    });
    g.bench_function("naive_sort_baseline", |b| {
        b.iter(|| temporal_median_naive(black_box(&frames)).unwrap())
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
