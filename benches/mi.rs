//! MI kernel throughput: the fast f32 kernel (project + sample + joint histogram) against the
//! straightforward f64 version through `CameraModel`, at three point counts, and the smooth
//! (partial-volume) estimator's value and value + gradient on the same points.
//!
//! Two groups of the same benchmarks: `mi_kernel` times wall clock (criterion's default),
//! `mi_kernel_cpu` the benchmark thread's own CPU time (`CLOCK_THREAD_CPUTIME_ID`). On a shared
//! machine the wall clock also counts the time other processes hold the core; the thread's CPU
//! time does not, so it is the per-core figure (still slightly pessimistic: other processes
//! evict the kernel's caches between time slices).
//!
//! Run: `taskset -c 1 cargo bench --bench mi` (one core, one thread). Figures: docs/benchmarks.md
//! "MI kernel".

use criterion::measurement::{Measurement, ValueFormatter};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use infraloc::camera::{Camera, CameraModel, Equidistant, Mei};
use infraloc::localize::mi::kernel::{
    accumulate, accumulate_scalar, BinnedImage, FastCamera, PoseF32, Scratch,
};
use infraloc::localize::mi::points::PreparedPoints;
use infraloc::localize::mi::smooth::{Pooling, Smooth, SmoothView};
use infraloc::localize::mi::{bin_lut, Binning, JointHist};
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

/// The calling thread's CPU time in nanoseconds.
fn thread_cpu_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid timespec to write; the clock id is a constant Linux provides.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    assert_eq!(rc, 0, "clock_gettime(CLOCK_THREAD_CPUTIME_ID) failed");
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// Criterion measurement: CPU time of the benchmarking thread (ns).
struct ThreadCpuTime;

impl Measurement for ThreadCpuTime {
    type Intermediate = u64;
    type Value = u64;
    fn start(&self) -> u64 {
        thread_cpu_ns()
    }
    fn end(&self, i: u64) -> u64 {
        thread_cpu_ns().saturating_sub(i)
    }
    fn add(&self, a: &u64, b: &u64) -> u64 {
        a + b
    }
    fn zero(&self) -> u64 {
        0
    }
    fn to_f64(&self, v: &u64) -> f64 {
        *v as f64
    }
    fn formatter(&self) -> &dyn ValueFormatter {
        &CpuFormatter
    }
}

/// Formats CPU nanoseconds as "µs cpu" etc., throughput as elements per CPU second.
struct CpuFormatter;

impl ValueFormatter for CpuFormatter {
    fn scale_values(&self, ns: f64, values: &mut [f64]) -> &'static str {
        let (factor, unit) = if ns < 1e3 {
            (1.0, "ns cpu")
        } else if ns < 1e6 {
            (1e-3, "µs cpu")
        } else if ns < 1e9 {
            (1e-6, "ms cpu")
        } else {
            (1e-9, "s cpu")
        };
        values.iter_mut().for_each(|v| *v *= factor);
        unit
    }
    fn scale_throughputs(&self, _typical: f64, t: &Throughput, values: &mut [f64]) -> &'static str {
        let n = match *t {
            Throughput::Elements(n) | Throughput::ElementsAndBytes { elements: n, .. } => n,
            Throughput::Bytes(n) | Throughput::BytesDecimal(n) => n,
            Throughput::Bits(n) => n,
        } as f64;
        values.iter_mut().for_each(|v| *v = n * 1e9 / *v / 1e6);
        "M/cpu-s"
    }
    fn scale_for_machines(&self, _values: &mut [f64]) -> &'static str {
        "ns"
    }
}

fn bench_wall(c: &mut Criterion) {
    bench_kernel(c, "mi_kernel");
}

fn bench_cpu(c: &mut Criterion<ThreadCpuTime>) {
    bench_kernel(c, "mi_kernel_cpu");
}

fn bench_kernel<M: Measurement>(c: &mut Criterion<M>, group: &str) {
    let tex = Texture::new(1);
    let center = Point3::new(100.0, 200.0, 6.0);
    let pose = CamFromMap::from_center_ypr(&center, 0.3, 0.01, -0.02);
    let origin = [center.x, center.y, center.z];
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let bins = 32;
    let lut = bin_lut(Binning::Uniform, bins, &[0; 256]);
    let mut g = c.benchmark_group(group);
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
            // The smooth (partial-volume) estimator on the same points and image: its value, and
            // its value with the 6-DoF gradient (two passes over the points).
            if n <= 200_000 {
                let view = SmoothView {
                    img: &img,
                    pts: &prepared,
                };
                let est = Smooth::new(&cam, vec![view], origin, bins, bins, true, Pooling::Joint);
                for (what, grad) in [("pv_value", false), ("pv_gradient", true)] {
                    g.bench_with_input(
                        BenchmarkId::new(format!("{what}_{name}"), n),
                        &n,
                        |b, _| b.iter(|| black_box(est.evaluate(black_box(&pose), grad))),
                    );
                }
            }
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

criterion_group!(wall, bench_wall);
criterion_group! {
    name = cpu;
    config = Criterion::default().with_measurement(ThreadCpuTime);
    targets = bench_cpu
}
criterion_main!(wall, cpu);
