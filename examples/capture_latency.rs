//! Capture latency against a GigE Vision camera (e.g. Aravis's fake camera): for each frame,
//! the time from Aravis completing it on this host (its buffer's system timestamp) to our
//! `grab` returning it as gray — conversion included — compared with the frame period.
//!
//! ```sh
//! /opt/aravis-tools/usr/bin/arv-fake-gv-camera-0.8 -i 127.0.0.1 &
//! cargo run --release --features aravis --example capture_latency -- 127.0.0.1 200 Mono8 2048
//! ```
//! Arguments: camera id, frames, pixel format, square region side (optional).

use infraloc::capture::{AravisSettings, AravisSource, FrameSource};
use std::time::{Duration, SystemTime};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let id = args.first().map(String::as_str).unwrap_or("127.0.0.1");
    let n: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(200);
    let format = args.get(2).cloned().unwrap_or_else(|| "Mono8".into());
    let side: Option<u32> = args.get(3).and_then(|s| s.parse().ok());
    let mut src = AravisSource::new(
        Some(id),
        AravisSettings {
            pixel_format: Some(format.clone()),
            region: side.map(|s| [0, 0, s, s]),
            ..Default::default()
        },
    );
    if let Err(e) = src.open() {
        eprintln!("camera {id}: {} [{}]", e.detail, e.fault);
        std::process::exit(1);
    }
    let timeout = Duration::from_secs(2);
    // Drain what queued up while opening, so every measured frame is fresh.
    for _ in 0..4 {
        let _ = src.grab(timeout);
    }
    let mut lat = Vec::with_capacity(n);
    let mut stamps = Vec::with_capacity(n);
    let mut size = (0, 0);
    for _ in 0..n {
        let f = match src.grab(timeout) {
            Ok(f) => f,
            Err(e) => {
                eprintln!("grab: {} [{}]", e.detail, e.fault);
                continue;
            }
        };
        let returned = SystemTime::now();
        lat.push(returned.duration_since(f.timestamp).unwrap_or_default());
        stamps.push(f.timestamp);
        size = f.image.dimensions();
    }
    src.close();
    if lat.len() < 2 {
        eprintln!("too few frames");
        std::process::exit(1);
    }
    let mut periods: Vec<Duration> = stamps
        .windows(2)
        .filter_map(|w| w[1].duration_since(w[0]).ok())
        .collect();
    periods.sort();
    lat.sort();
    let q = |v: &[Duration], p: f64| v[((v.len() - 1) as f64 * p).round() as usize];
    let period = q(&periods, 0.5);
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    println!(
        "{} frames {}x{} {format}: frame period {:.2} ms; latency median {:.3} ms, p95 {:.3} ms, \
         max {:.3} ms; p95/period = {:.3}",
        lat.len(),
        size.0,
        size.1,
        ms(period),
        ms(q(&lat, 0.5)),
        ms(q(&lat, 0.95)),
        ms(*lat.last().unwrap()),
        q(&lat, 0.95).as_secs_f64() / period.as_secs_f64()
    );
}
