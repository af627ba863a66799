//! `infraloc simulate --times K`: one scene captured at K times of a day. The captures differ
//! in the sun (and so in their shadows) and traffic; the pose, map tile and camera file are
//! the single capture's; a single capture is byte for byte what it was before times existed.

use crate::common::{infraloc, s};
use std::collections::BTreeMap;
use std::path::Path;

/// The scene of these tests: small, easy (no calibration views to render), two frames a time.
fn simulate(out: &Path, extra: &[&str]) {
    let mut args = vec![
        "simulate",
        "--out",
        s(out),
        "--seed",
        "11",
        "--preset",
        "small",
    ];
    args.extend(["--difficulty", "easy", "--frames", "2"]);
    args.extend(extra);
    let o = infraloc(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// Every file under `dir` by its relative path ('/'-separated, sorted as strings).
fn files(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    crate::common::tree_files(dir)
        .into_iter()
        .map(|(p, b)| (p.to_string_lossy().replace('\\', "/"), b))
        .collect()
}

/// FNV-1a (64 bit) of every file's path, a NUL and its bytes, in path order.
fn fnv(files: &BTreeMap<String, Vec<u8>>) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for (p, bytes) in files {
        for b in p.bytes().chain([0]).chain(bytes.iter().copied()) {
            h ^= b as u64;
            h = h.wrapping_mul(0x100_0000_01b3);
        }
    }
    h
}

fn gray(path: &Path) -> image::GrayImage {
    image::open(path).unwrap().to_luma8()
}

/// The fraction of pixels within 40 % of the width from the centre that hold still within each
/// of two bursts (the frames of one capture within 15 % of each other: no traffic crossed
/// them) and yet change by more than 30 % from one capture to the other: static content lit
/// differently, that is, shadows that moved.
fn moved_shadows(a: [&image::GrayImage; 2], b: [&image::GrayImage; 2]) -> f64 {
    let (w, h) = a[0].dimensions();
    let ratio = |x: u8, y: u8| {
        let (x, y) = (x as f64 + 1.0, y as f64 + 1.0);
        (x / y).min(y / x)
    };
    let (mut inside, mut moved) = (0usize, 0usize);
    for y in 0..h {
        for x in 0..w {
            let (dx, dy) = (x as f64 - w as f64 / 2.0, y as f64 - h as f64 / 2.0);
            if dx.hypot(dy) > 0.4 * w as f64 {
                continue;
            }
            inside += 1;
            let p = |i: &image::GrayImage| i.get_pixel(x, y)[0];
            let still = ratio(p(a[0]), p(a[1])) > 0.85 && ratio(p(b[0]), p(b[1])) > 0.85;
            if still && ratio(p(a[0]), p(b[0])) < 0.7 {
                moved += 1;
            }
        }
    }
    moved as f64 / inside as f64
}

#[test]
fn times_share_the_map_and_differ_in_sun_and_shadows_and_one_time_is_unchanged() {
    let tmp = tempfile::tempdir().unwrap();
    let (one, three) = (tmp.path().join("one"), tmp.path().join("three"));
    simulate(&one, &["--times", "1"]);
    simulate(&three, &["--times", "3"]);
    let (f1, f3) = (files(&one), files(&three));

    // One time: the bytes of the simulator before `--times` existed (the same seed, settings
    // and file list; floating-point rendering pins this to one architecture). The scene's
    // infraloc.toml is left out: it lists every config key with its default, and grows with them.
    assert!(
        !f1.keys().any(|k| k.starts_with("times/")),
        "{:?}",
        f1.keys()
    );
    #[cfg(target_arch = "x86_64")]
    {
        let mut rendered = f1.clone();
        rendered.remove("infraloc.toml");
        assert_eq!(
            fnv(&rendered),
            0x075e_16b8_6c98_10b9,
            "the single capture changed"
        );
    }

    // Three times: the same map tile and camera file, three captures of two frames each and
    // their medians.
    for (k, v) in f1.iter().filter(|(k, _)| k.starts_with("tiles/")) {
        assert!(
            f3.get(k) == Some(v),
            "{k} differs between one and three times"
        );
    }
    assert_eq!(f1["camera.yaml"], f3["camera.yaml"]);
    for t in 0..3 {
        for f in ["000.png", "001.png"] {
            assert!(
                f3.contains_key(&format!("times/{t:02}/{f}")),
                "times/{t:02}/{f}"
            );
        }
        assert!(f3.contains_key(&format!("times/{t:02}.png")));
    }
    assert!(!f3.contains_key("times/03.png"));
    assert_eq!(
        f3["frames/000.png"], f3["times/00/000.png"],
        "frames/ is time 0"
    );

    let truth: serde_json::Value = serde_json::from_slice(&f3["truth.json"]).unwrap();
    let times = truth["acquisition"]["times"].as_array().unwrap();
    assert_eq!(times.len(), 3);
    assert_eq!(truth["settings"]["times"], 3);
    let utc: Vec<&str> = times.iter().map(|t| t["utc"].as_str().unwrap()).collect();
    let sun: Vec<[f64; 2]> = times
        .iter()
        .map(|t| serde_json::from_value(t["sun_az_el_deg"].clone()).unwrap())
        .collect();
    assert!(utc.windows(2).all(|w| w[0] < w[1]), "{utc:?}");
    assert_eq!(truth["timestamp_utc"].as_str(), Some(utc[0]), "{truth}");
    for w in sun.windows(2) {
        assert!((w[0][0] - w[1][0]).abs() > 10.0, "{sun:?}");
    }
    assert!(sun.iter().all(|s| (18.0..=65.0).contains(&s[1])), "{sun:?}");
    assert_eq!(
        truth["acquisition"]["camera_sun_az_el_deg"],
        times[0]["sun_az_el_deg"]
    );

    // The shadows moved between captures.
    let g = |t: usize, f: usize| gray(&three.join(format!("times/{t:02}/{f:03}.png")));
    let (a, b) = ([g(0, 0), g(0, 1)], [g(2, 0), g(2, 1)]);
    let moved = moved_shadows([&a[0], &a[1]], [&b[0], &b[1]]);
    assert!(moved > 0.015, "{moved}");
}

#[test]
fn bad_times_name_the_flag() {
    let tmp = tempfile::tempdir().unwrap();
    for bad in ["0", "25"] {
        let out = tmp.path().join("bad");
        let o = infraloc(&[
            "simulate",
            "--out",
            s(&out),
            "--preset",
            "small",
            "--times",
            bad,
        ]);
        assert!(!o.status.success());
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            err.contains("--times") && err.trim().lines().count() == 1,
            "{err}"
        );
    }
}
