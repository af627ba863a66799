//! Capture latency against a GigE Vision camera (e.g. Aravis's fake camera), compared with the
//! frame period:
//! - *age*: from Aravis completing the frame on this host (its buffer's system timestamp) to
//!   our `grab` returning it as gray, conversion included;
//! - *wait*: from calling `grab` (after idling, as the burst does between frames) to its
//!   return. Stale queued frames are dropped, so this is at most one period plus the age.
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
    let mut waits = Vec::with_capacity(n);
    // Idle between grabs like a burst does, long enough for every buffer to fill up.
    let idle = Duration::from_millis(250);
    let mut stamps = Vec::with_capacity(n);
    let mut seqs = Vec::with_capacity(n);
    let mut size = (0, 0);
    for _ in 0..n {
        std::thread::sleep(idle);
        let asked = SystemTime::now();
        let f = match src.grab(timeout) {
            Ok(f) => f,
            Err(e) => {
                eprintln!("grab: {} [{}]", e.detail, e.fault);
                continue;
            }
        };
        let returned = SystemTime::now();
        lat.push(returned.duration_since(f.timestamp).unwrap_or_default());
        waits.push(returned.duration_since(asked).unwrap_or_default());
        stamps.push(f.timestamp);
        seqs.push(f.sequence);
        size = f.image.dimensions();
    }
    src.close();
    if lat.len() < 2 {
        eprintln!("too few frames");
        std::process::exit(1);
    }
    // The camera's frame period from its own timestamps: consecutive returned frames are
    // `idle + wait` apart, so use the sequence numbers to divide.
    let mut periods: Vec<Duration> = stamps
        .windows(2)
        .zip(seqs.windows(2))
        .filter_map(|(t, s)| {
            let dt = t[1].duration_since(t[0]).ok()?;
            let frames = u32::try_from(s[1].checked_sub(s[0])?).ok()?;
            (frames > 0).then(|| dt / frames)
        })
        .collect();
    periods.sort();
    waits.sort();
    lat.sort();
    let q = |v: &[Duration], p: f64| v[((v.len() - 1) as f64 * p).round() as usize];
    let period = q(&periods, 0.5);
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    println!(
        "{} frames {}x{} {format}: frame period {:.2} ms; age median {:.3} ms, p95 {:.3} ms, \
         max {:.3} ms; wait median {:.2} ms, p95 {:.2} ms, max {:.2} ms; \
         max wait / period = {:.3}",
        lat.len(),
        size.0,
        size.1,
        ms(period),
        ms(q(&lat, 0.5)),
        ms(q(&lat, 0.95)),
        ms(*lat.last().unwrap()),
        ms(q(&waits, 0.5)),
        ms(q(&waits, 0.95)),
        ms(*waits.last().unwrap()),
        waits.last().unwrap().as_secs_f64() / period.as_secs_f64()
    );
}
