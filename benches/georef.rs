//! Georeferencing throughput (docs/benchmarks.md "Georeferencing"): every 4th pixel of a 5 MP
//! 185° fisheye (2448 × 2048, a 6 m pole, 5° tilt) met with a 60 m × 60 m height layer at 0.1 m
//! (camber, a 3 % ramp and ripples), with the pose covariance propagated — on one thread (the
//! per-core rate) and on two (the lookup table's case), as a batch and as the service's lookup
//! table (`lut_*`: the table's cells and its NPY bytes).
//!
//! Run: `cargo bench --bench georef`

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use infraloc::camera::Mei;
use infraloc::geo::georef::{
    georef_batch, lookup_table, HeightSurface, Params, PoseCovariance, PoseWithCovariance, Surface,
};
use infraloc::map::{Crs, GeoGrid, Raster};
use infraloc::pose::CamFromMap;
use nalgebra::Point3;
use std::hint::black_box;

fn camera() -> Mei {
    Mei {
        width: 2448,
        height: 2048,
        fx: 800.0,
        fy: 800.0,
        cx: 1223.5,
        cy: 1023.5,
        skew: 0.0,
        xi: 1.2,
        k1: -0.03,
        k2: 0.01,
        p1: 0.0,
        p2: 0.0,
        fov_deg: Some(185.0),
    }
}

fn heights() -> Raster<f32> {
    let g = GeoGrid {
        crs: Crs::Epsg(32632),
        x0: 690_000.0 - 30.0,
        y0: 5_330_000.0 + 30.0,
        res: 0.1,
        width: 600,
        height: 600,
    };
    let mut r = Raster::filled(g, 0.0f32, Some(-9999.0));
    for row in 0..g.height {
        for col in 0..g.width {
            let (x, y) = (col as f64 * 0.1 - 30.0, 30.0 - row as f64 * 0.1);
            let camber = -0.02 * (y.abs() - 3.5).abs();
            let h = 500.0 + 0.03 * x + camber + 0.02 * (0.7 * x).sin() * (0.5 * y).cos();
            r.data[row * g.width + col] = h as f32;
        }
    }
    r
}

fn bench_georef(c: &mut Criterion) {
    let cam = camera();
    let h = heights();
    let surface = Surface::Heights(HeightSurface::new(&h).expect("heights"));
    let pose = PoseWithCovariance {
        pose: CamFromMap::from_center_ypr(
            &Point3::new(690_000.3, 5_330_000.2, 506.0),
            0.4,
            5f64.to_radians(),
            0.0,
        ),
        covariance: Some(PoseCovariance::from_sigma([
            0.01, 0.01, 0.02, 0.02, 0.01, 0.01,
        ])),
    };
    let pixels: Vec<[f64; 2]> = (0..2048)
        .step_by(4)
        .flat_map(|v| (0..2448).step_by(4).map(move |u| [u as f64, v as f64]))
        .collect();
    let params = Params {
        wgs84: false,
        height_sigma_m: None,
        ..Params::default()
    };
    let crs = h.grid.crs;
    // The pixels whose ray meets the layer: the per-core rate of the issue is on these.
    let ground: Vec<[f64; 2]> = georef_batch(&cam, &pose, &surface, crs, &pixels, &params)
        .iter()
        .zip(&pixels)
        .filter(|(m, _)| m.status == infraloc::geo::georef::Status::Ok)
        .map(|(_, p)| *p)
        .collect();
    eprintln!("{} pixels, {} on the ground", pixels.len(), ground.len());
    let pools: Vec<(usize, rayon::ThreadPool)> = [1usize, 2]
        .into_iter()
        .map(|n| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(n).build();
            (n, pool.expect("pool"))
        })
        .collect();
    let mut g = c.benchmark_group("georef_5mp_step4");
    g.sample_size(10);
    g.throughput(Throughput::Elements(pixels.len() as u64));
    for (threads, pool) in &pools {
        g.bench_function(format!("{threads}_thread"), |b| {
            b.iter(|| {
                pool.install(|| {
                    black_box(georef_batch(&cam, &pose, &surface, crs, &pixels, &params))
                })
            })
        });
        // The service's lookup table itself: the same pixels, the table's cells and the NPY
        // bytes it writes.
        g.bench_function(format!("lut_{threads}_thread"), |b| {
            b.iter(|| {
                pool.install(|| {
                    let lut = lookup_table(&cam, &pose, &surface, 4, &params);
                    black_box(infraloc::georef::npy_bytes(&lut))
                })
            })
        });
    }
    g.finish();
    // The pixels that meet the layer alone: the per-core rate on the height layer.
    let mut g = c.benchmark_group("georef_5mp_step4_ground");
    g.sample_size(10);
    g.throughput(Throughput::Elements(ground.len() as u64));
    for (threads, pool) in &pools {
        let run = || georef_batch(&cam, &pose, &surface, crs, &ground, &params);
        g.bench_function(format!("{threads}_thread"), |b| {
            b.iter(|| pool.install(|| black_box(run())))
        });
    }
    g.finish();
}

criterion_group!(benches, bench_georef);
criterion_main!(benches);
