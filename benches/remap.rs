//! Gray bilinear remap of a 5 MP frame (2448×2048) with a fisheye→perspective map: the fixed-point
//! [`RemapTable`] against the plain f32 baseline, on 1 and 2 rayon threads. OpenCV's figure for the
//! same size and map comes from `benches/opencv_remap.py` (see docs/benchmarks.md, "Remap").

use criterion::{criterion_group, criterion_main, Criterion};
use infraloc::camera::rectify::{perspective_map, remap_bilinear_f32, GrayView, RemapTable};
use infraloc::camera::Equidistant;
use nalgebra::Matrix3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;

const W: usize = 2448;
const H: usize = 2048;

/// The 185° equidistant lens of a 5 MP frame and a 120°-wide perspective view of it; the same
/// numbers are in benches/opencv_remap.py.
fn setup() -> (Vec<u8>, infraloc::camera::rectify::RectifyMap) {
    let cam = Equidistant {
        width: W as u32,
        height: H as u32,
        fx: 640.0,
        fy: 640.0,
        cx: 1224.0,
        cy: 1024.0,
        alpha: 0.0,
        k1: 0.0,
        k2: 0.0,
        k3: 0.0,
        k4: 0.0,
        fov_deg: Some(185.0),
        cache: Default::default(),
    };
    let p = Matrix3::new(700.0, 0.0, 1224.0, 0.0, 700.0, 1024.0, 0.0, 0.0, 1.0);
    let map = perspective_map(&cam, &p, &Matrix3::identity(), W, H).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let img: Vec<u8> = (0..W * H).map(|_| rng.random::<u8>()).collect();
    (img, map)
}

fn bench(c: &mut Criterion) {
    let (img, map) = setup();
    let src = GrayView::new(&img, W, H).unwrap();
    let mut g = c.benchmark_group("remap_5mp");
    g.sample_size(30);
    for threads in [1usize, 2] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let table = pool.install(|| RemapTable::new(&map, W, H).unwrap());
        let mut out = vec![0u8; W * H];
        g.bench_function(format!("fixed_point/threads={threads}"), |b| {
            b.iter(|| pool.install(|| table.remap_into(black_box(&src), &mut out).unwrap()))
        });
        g.bench_function(format!("f32_baseline/threads={threads}"), |b| {
            b.iter(|| pool.install(|| remap_bilinear_f32(black_box(&src), &map).unwrap()))
        });
        g.bench_function(format!("table_build/threads={threads}"), |b| {
            b.iter(|| pool.install(|| RemapTable::new(black_box(&map), W, H).unwrap()))
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
