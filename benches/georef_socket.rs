//! The service's `georef` request over its control socket (docs/benchmarks.md
//! "Georeferencing"): the real `infraloc daemon` serving a simulated scene's truth as its pose,
//! asked for 1,000 pixels (a 40 × 25 grid over the image) by a client that connects, sends the
//! frame and parses the answer, as a pipeline would. `status` over the same socket, in the same
//! run, is the baseline: the round trip without the georeferencing.
//!
//! Run: `cargo bench --all-features --bench georef_socket` (the daemon needs the `v4l` feature:
//! its camera is an absent V4L2 device, so the stored pose stays served)

use criterion::{criterion_group, criterion_main, Criterion};
use infraloc::control::{Client, Request};
use serde_json::Value;
use std::hint::black_box;
use std::time::{Duration, Instant};

#[path = "../tests/it/common/served.rs"]
mod served;
use served::{grid_1000, raw, simulate, store_truth, write_config, Daemon};

fn bench_socket(c: &mut Criterion) {
    let dir = tempfile::tempdir().expect("tempdir");
    let (scene, work) = (dir.path().join("scene"), dir.path().join("work"));
    std::fs::create_dir_all(&work).expect("work dir");
    simulate(&scene);
    let cfg = write_config(&scene, &work, false);
    store_truth(&scene, &work);
    let mut d = Daemon::start(&cfg);
    d.wait_status(&cfg, |v| !v["last_result"].is_null());
    let socket = work.join("run/control.sock");
    let st = raw(&socket, &serde_json::json!({"request": "status"}));
    assert_eq!(st["ok"], true, "{st}");
    let camera = infraloc::camera::load_camera(&scene.join("camera.yaml")).expect("camera");
    let (w, h) = (
        infraloc::camera::CameraModel::width(&camera) as f64,
        infraloc::camera::CameraModel::height(&camera) as f64,
    );
    let grid = grid_1000(w, h);
    let georef = Request::Georef {
        pixels: grid,
        sigma_px: 0.0,
        height_sigma_m: None,
    };
    // Wait until the service holds the pose's georeferencing.
    let start = Instant::now();
    loop {
        let a = Client::connect(&socket)
            .and_then(|mut c| c.call(&georef, Duration::from_secs(30), |_| {}))
            .expect("georef request");
        if a.refusal().is_none() {
            break;
        }
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "{:?}",
            a.refusal()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    let call = |req: &Request| {
        let a = Client::connect(&socket)
            .and_then(|mut c| c.call(req, Duration::from_secs(30), |_| {}))
            .expect("request");
        assert_eq!(a.refusal(), None);
        let v: Value = a.parse("answer").expect("answer");
        black_box(v)
    };
    let mut g = c.benchmark_group("socket");
    g.sample_size(30);
    g.bench_function("georef_1000_px", |b| b.iter(|| call(&georef)));
    g.bench_function("status", |b| b.iter(|| call(&Request::Status {})));
    g.finish();
    drop(d);
}

criterion_group!(benches, bench_socket);
criterion_main!(benches);
