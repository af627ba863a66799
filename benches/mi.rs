//! MI kernel throughput: the fast f32 kernel (project + sample + joint histogram) against the
//! straightforward f64 version through `CameraModel`, at three point counts.
//!
//! Run: `CARGO_TARGET_DIR=… cargo bench --bench mi`. Figures: docs/benchmarks.md "MI kernel".

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use infraloc::camera::{Camera, CameraModel, Equidistant, Mei};
use infraloc::localize::kernel::{
    accumulate, accumulate_scalar, BinnedImage, FastCamera, PoseF32, Scratch,
};
use infraloc::localize::mi::{bin_lut, Binning, JointHist};
use infraloc::localize::points::PreparedPoints;
use infraloc::localize::synth::{ground_points, Texture};
use infraloc::pose::CamFromMap;
use nalgebra::Point3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;

/// A 5 MP-class 185° fisheye (Mei, ξ ≈ 1.2) at 2048×2048.
fn mei() -> Camera {
    Camera::Mei(Mei {
        width: 2048,
        height: 2048,
        fx: 1150.0,
        fy: 1150.0,
        cx: 1023.5,
        cy: 1023.5,
        skew: 0.0,
        xi: 1.2,
        k1: -0.05,
        k2: 0.01,
        p1: 1e-4,
        p2: -1e-4,
        fov_deg: Some(185.0),
    })
}

fn equidistant() -> Camera {
    Camera::Equidistant(Equidistant {
        width: 2048,
        height: 2048,
        fx: 640.0,
        fy: 640.0,
        cx: 1023.5,
        cy: 1023.5,
        alpha: 0.0,
        k1: 0.01,
        k2: -0.002,
        k3: 0.0,
        k4: 0.0,
        fov_deg: Some(185.0),
        cache: Default::default(),
    })
}

fn bench_kernel(c: &mut Criterion) {
    let tex = Texture::new(1);
    let center = Point3::new(100.0, 200.0, 6.0);
    let pose = CamFromMap::from_center_ypr(&center, 0.3, 0.01, -0.02);
    let origin = [center.x, center.y, center.z];
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let bins = 32;
    let lut = bin_lut(Binning::Uniform, bins, &[0; 256]);
    let mut g = c.benchmark_group("mi_kernel");
    g.sample_size(20);
    g.warm_up_time(std::time::Duration::from_secs(1));
    g.measurement_time(std::time::Duration::from_secs(3));
    for (name, cam) in [("mei", mei()), ("equidistant", equidistant())] {
        let (w, h) = (cam.width() as usize, cam.height() as usize);
        let mask = cam.valid_mask();
        let gray: Vec<u8> = (0..w * h).map(|_| rng.random()).collect();
        let img = BinnedImage::new(w, h, &gray, &mask, &lut, bins as u8);
        let fast = FastCamera::new(&cam, 0);
        let p32 = PoseF32::new(&pose, origin);
        // Radius 25 m; spacings giving ≈ 10 k, 100 k and 1 M points.
        let spacings: &[f64] = if name == "mei" {
            &[0.44, 0.14, 0.044]
        } else {
            &[0.14]
        };
        for &sp in spacings {
            let pts = ground_points(&tex, (center.x, center.y), 25.0, sp, 0.0, 3.0, 3);
            let prepared = PreparedPoints::new(&pts, origin, &lut);
            let n = pts.len();
            g.throughput(Throughput::Elements(n as u64));
            let mut scratch = Scratch::default();
            g.bench_with_input(BenchmarkId::new(format!("fast_{name}"), n), &n, |b, _| {
                b.iter(|| {
                    let mut hist = JointHist::new(bins, bins);
                    accumulate(
                        black_box(&prepared),
                        &p32,
                        &fast,
                        &img,
                        &mut hist,
                        &mut scratch,
                    );
                    black_box(hist)
                })
            });
            if n <= 200_000 {
                g.bench_with_input(BenchmarkId::new(format!("scalar_{name}"), n), &n, |b, _| {
                    b.iter(|| {
                        let mut hist = JointHist::new(bins, bins);
                        accumulate_scalar(
                            black_box(&pts),
                            &pose,
                            &cam,
                            &gray,
                            &mask,
                            &lut,
                            &lut,
                            &mut hist,
                        );
                        black_box(hist)
                    })
                });
            }
        }
    }
    g.finish();
}

criterion_group!(benches, bench_kernel);
criterion_main!(benches);
