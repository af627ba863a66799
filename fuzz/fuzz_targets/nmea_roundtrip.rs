//! A fix built from arbitrary bytes, written as GGA and RMC sentences and parsed back: the
//! values must survive to the written precision.
#![no_main]

use infraloc::gnss::nmea::{self, Body, Date, LatLon, UtcTime, WRITE_MINUTE_DECIMALS};
use libfuzzer_sys::fuzz_target;

fn take<const N: usize>(d: &mut &[u8]) -> [u8; N] {
    let mut out = [0u8; N];
    let n = N.min(d.len());
    out[..n].copy_from_slice(&d[..n]);
    *d = &d[n..];
    out
}

fuzz_target!(|data: &[u8]| {
    let mut d = data;
    let u = |b: [u8; 8]| u64::from_le_bytes(b) as f64 / u64::MAX as f64;
    let lat = u(take(&mut d)) * 180.0 - 90.0;
    let lon = u(take(&mut d)) * 360.0 - 180.0;
    let alt = u(take(&mut d)) * 20_000.0 - 1_000.0;
    let [h, m, s, q, sats, hd, dd, mm, yy] = take::<9>(&mut d);
    let [ms0, ms1] = take::<2>(&mut d);
    let time = UtcTime {
        hour: h % 24,
        minute: m % 60,
        second: s % 61,
        millis: u16::from_le_bytes([ms0, ms1]) % 1000,
        has_fraction: true,
    };
    let quality = q % 8 + 1;
    let hdop = hd as f64 / 10.0;
    let Some(date) = Date::new(2000 + (yy % 80) as u16, mm % 12 + 1, dd % 31 + 1) else {
        return;
    };
    let pos = LatLon { lat, lon };
    // Half a unit of the last written minute digit, in degrees, plus float slack.
    let tol = 0.5 * 10f64.powi(-(WRITE_MINUTE_DECIMALS as i32)) / 60.0 + 1e-12;

    let mut line = String::new();
    nmea::write_gga(&mut line, &time, pos, quality, sats % 100, hdop, alt, 0.0);
    let p = nmea::parse(line.as_bytes()).unwrap_or_else(|e| panic!("{line}: {e}"));
    let Body::Gga(g) = p.body else {
        panic!("{line}")
    };
    let back = g.pos.unwrap();
    assert!(
        (back.lat - lat).abs() <= tol && (back.lon - lon).abs() <= tol,
        "{line}"
    );
    assert_eq!(g.time, Some(time), "{line}");
    assert_eq!(g.quality, quality);
    assert!((g.alt_msl.unwrap() - alt).abs() <= 0.0005 + 1e-9, "{line}");
    assert!((g.hdop.unwrap() - hdop).abs() <= 0.005 + 1e-9, "{line}");

    line.clear();
    let mode = b"ADPRFEMS"[(q % 8) as usize];
    nmea::write_rmc(&mut line, &time, &date, pos, mode);
    let p = nmea::parse(line.as_bytes()).unwrap_or_else(|e| panic!("{line}: {e}"));
    let Body::Rmc(r) = p.body else {
        panic!("{line}")
    };
    assert_eq!(r.date, Some(date), "{line}");
    assert_eq!(r.time, Some(time), "{line}");
    let (back, q2) = p.position().unwrap();
    assert_eq!(q2, nmea::quality::from_mode(mode));
    assert!(
        (back.lat - lat).abs() <= tol && (back.lon - lon).abs() <= tol,
        "{line}"
    );
});
