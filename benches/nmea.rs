//! NMEA parsing throughput on the sentences of all real receiver logs in `shared/data/nmea`
//! (every sentence type those receivers emit, ~2 200 lines), against two baselines in the same
//! run: the `nmea` crate (0.8) and a naive `String`-splitting parser of GGA/RMC.
//! `cargo bench --bench nmea` (set `INFRALOC_SHARED_DATA` if `../shared/data` is elsewhere).

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use infraloc::gnss::{nmea as ours, Decoder};
use std::hint::black_box;
use std::path::PathBuf;

fn data_dir() -> PathBuf {
    match std::env::var_os("INFRALOC_SHARED_DATA") {
        Some(d) => PathBuf::from(d).join("nmea"),
        None => PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data/nmea")),
    }
}

fn corpus() -> (Vec<String>, Vec<u8>) {
    let mut lines = Vec::new();
    let mut raw = Vec::new();
    let mut paths: Vec<_> = std::fs::read_dir(data_dir())
        .expect("shared/data/nmea (set INFRALOC_SHARED_DATA)")
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "log"))
        .collect();
    paths.sort();
    for p in paths {
        let text = std::fs::read_to_string(&p).unwrap();
        raw.extend_from_slice(text.as_bytes());
        lines.extend(
            text.lines()
                .filter(|l| l.starts_with('$'))
                .map(str::to_string),
        );
    }
    (lines, raw)
}

/// What a quick hand-written parser looks like: split into owned Strings, parse with `str::parse`.
fn naive(line: &str) -> Option<(f64, f64)> {
    let (data, cs) = line
        .strip_prefix('$')?
        .split_once('*')
        .unwrap_or((line, ""));
    if !cs.is_empty() {
        let want = u8::from_str_radix(cs, 16).ok()?;
        if data.bytes().fold(0, |a, b| a ^ b) != want {
            return None;
        }
    }
    let f: Vec<String> = data.split(',').map(|s| s.to_string()).collect();
    let (lat_i, hemi_i) = match f.first()?.get(2..)? {
        "GGA" => (2, 3),
        "RMC" => (3, 4),
        _ => return None,
    };
    let coord = |v: &str, deg_digits: usize| -> Option<f64> {
        let d: f64 = v.get(..deg_digits)?.parse().ok()?;
        let m: f64 = v.get(deg_digits..)?.parse().ok()?;
        Some(d + m / 60.0)
    };
    let lat = coord(f.get(lat_i)?, 2)?;
    let lon = coord(f.get(lat_i + 2)?, 3)?;
    let lat = if f.get(hemi_i)? == "S" { -lat } else { lat };
    let lon = if f.get(hemi_i + 2)? == "W" { -lon } else { lon };
    Some((lat, lon))
}

fn bench(c: &mut Criterion) {
    let (lines, raw) = corpus();
    let mut g = c.benchmark_group("nmea");
    g.throughput(Throughput::Elements(lines.len() as u64));
    g.bench_function("infraloc_parse", |b| {
        b.iter(|| {
            let mut ok = 0usize;
            for l in &lines {
                ok += ours::parse(black_box(l.as_bytes())).is_ok() as usize;
            }
            ok
        })
    });
    g.bench_function("nmea_crate_parse_str", |b| {
        b.iter(|| {
            let mut ok = 0usize;
            for l in &lines {
                ok += nmea::parse_str(black_box(l)).is_ok() as usize;
            }
            ok
        })
    });
    g.bench_function("naive_string_split", |b| {
        b.iter(|| {
            let mut ok = 0usize;
            for l in &lines {
                ok += naive(black_box(l)).is_some() as usize;
            }
            ok
        })
    });
    // Whole pipeline on the raw log bytes: framing + parsing + epoch merging.
    g.bench_function("infraloc_decoder_bytes", |b| {
        b.iter(|| {
            let mut d = Decoder::for_log_files();
            let mut n = 0usize;
            d.push(black_box(&raw), |_| n += 1);
            n
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
