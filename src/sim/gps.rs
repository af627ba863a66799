//! The simulated GNSS receiver: a biased, noisy track around the true position, as an NMEA 0183
//! log (GGA + RMC at 1 Hz, CRLF, checksums), formatted like a consumer receiver's output.

use crate::error::Result;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use std::fmt::Write as _;

/// Error model of the receiver.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct GpsModel {
    /// σ of the constant per-axis bias (multipath, atmosphere), metres.
    pub bias_sigma: f64,
    /// σ of the per-axis time-correlated noise, metres.
    pub noise_sigma: f64,
    /// Correlation time of the noise (first-order Gauss–Markov), seconds.
    pub tau_s: f64,
    /// Log length, seconds (one fix per second).
    pub duration_s: u32,
    /// GGA fix quality (1 = GPS, 2 = DGPS/SBAS).
    pub quality: u8,
    /// HDOP range.
    pub hdop: (f64, f64),
    /// Satellites-used range.
    pub sats: (u32, u32),
}

/// One epoch of the receiver's output.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Fix {
    /// Seconds after the log's start.
    pub secs: u32,
    /// Latitude, degrees.
    pub lat: f64,
    /// Longitude, degrees.
    pub lon: f64,
    /// Altitude above mean sea level, metres.
    pub alt_msl: f64,
    /// Satellites used.
    pub sats: u32,
    /// Horizontal dilution of precision.
    pub hdop: f64,
    /// Fix quality.
    pub quality: u8,
    /// Speed over ground, knots (noise only: the receiver is static).
    pub speed_kn: f64,
    /// Course over ground, degrees.
    pub course: f64,
}

/// UTC start of a log (no midnight crossing: callers start it before 22:00).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UtcStart {
    /// Year (4 digits).
    pub year: u32,
    /// Month 1..=12.
    pub month: u32,
    /// Day 1..=28.
    pub day: u32,
    /// Seconds of the day.
    pub sec_of_day: u32,
}

fn std_normal(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = rng.random_range(f64::MIN_POSITIVE..1.0);
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// Receiver track around the true map position `truth` (x, y, z): bias + Gauss–Markov noise per
/// axis. `to_wgs84` converts map (x, y) to (lat, lon); `geoid_sep` is N (ellipsoid − geoid), so
/// the map height `z` (orthometric) is reported as altitude MSL.
pub(crate) fn track(
    rng: &mut ChaCha8Rng,
    truth: [f64; 3],
    m: &GpsModel,
    to_wgs84: impl Fn(f64, f64) -> Result<(f64, f64)>,
) -> Result<Vec<Fix>> {
    let bias = [
        std_normal(rng) * m.bias_sigma,
        std_normal(rng) * m.bias_sigma,
        std_normal(rng) * m.bias_sigma * 1.5,
    ];
    let phi = (-1.0 / m.tau_s).exp();
    let drive = m.noise_sigma * (1.0 - phi * phi).sqrt();
    let mut n = [
        std_normal(rng) * m.noise_sigma,
        std_normal(rng) * m.noise_sigma,
        std_normal(rng) * m.noise_sigma * 1.5,
    ];
    let mut sats = rng.random_range(m.sats.0..=m.sats.1);
    let mut hdop = rng.random_range(m.hdop.0..m.hdop.1);
    let mut out = Vec::with_capacity(m.duration_s as usize);
    let mut prev = None;
    for secs in 0..m.duration_s {
        if secs > 0 {
            for (k, v) in n.iter_mut().enumerate() {
                let scale = if k == 2 { 1.5 } else { 1.0 };
                *v = phi * *v + drive * scale * std_normal(rng);
            }
            if rng.random_bool(0.05) {
                sats = (sats as i64 + rng.random_range(-1..=1))
                    .clamp(m.sats.0 as i64, m.sats.1 as i64) as u32;
                hdop = rng.random_range(m.hdop.0..m.hdop.1);
            }
        }
        let (x, y) = (truth[0] + bias[0] + n[0], truth[1] + bias[1] + n[1]);
        let (lat, lon) = to_wgs84(x, y)?;
        let (speed_kn, course) = match prev {
            Some((px, py)) => {
                let (dx, dy): (f64, f64) = (x - px, y - py);
                (
                    dx.hypot(dy) * 1.943_844,
                    dx.atan2(dy).to_degrees().rem_euclid(360.0),
                )
            }
            None => (0.0, 0.0),
        };
        prev = Some((x, y));
        out.push(Fix {
            secs,
            lat,
            lon,
            alt_msl: truth[2] + bias[2] + n[2],
            sats,
            hdop,
            quality: m.quality,
            speed_kn,
            course,
        });
    }
    Ok(out)
}

/// XOR checksum of the characters between `$` and `*`.
pub(crate) fn checksum(body: &str) -> u8 {
    body.bytes().fold(0, |a, b| a ^ b)
}

fn sentence(out: &mut String, body: &str) {
    let _ = write!(out, "${body}*{:02X}\r\n", checksum(body));
}

/// Degrees → NMEA `(d)ddmm.mmmmm` with hemisphere letter.
fn nmea_angle(deg: f64, lat: bool) -> String {
    let hemi = match (lat, deg >= 0.0) {
        (true, true) => 'N',
        (true, false) => 'S',
        (false, true) => 'E',
        (false, false) => 'W',
    };
    let a = deg.abs();
    // Round in minutes first so 59.999995 does not print as 60.00000.
    let total_min = (a * 60.0 * 1e5).round() / 1e5;
    let d = (total_min / 60.0).floor();
    let m = total_min - d * 60.0;
    if lat {
        format!("{:02}{:08.5},{hemi}", d as u32, m)
    } else {
        format!("{:03}{:08.5},{hemi}", d as u32, m)
    }
}

/// The NMEA log text: per epoch a GGA then an RMC sentence, CRLF line ends. `geoid_sep` is the
/// geoid separation reported in GGA, metres.
pub(crate) fn nmea_log(fixes: &[Fix], start: &UtcStart, geoid_sep: f64) -> String {
    let mut out = String::new();
    for f in fixes {
        let t = start.sec_of_day + f.secs;
        let hms = format!("{:02}{:02}{:02}.00", t / 3600, (t / 60) % 60, t % 60);
        let (lat, lon) = (nmea_angle(f.lat, true), nmea_angle(f.lon, false));
        let gga = format!(
            "GPGGA,{hms},{lat},{lon},{},{:02},{:.2},{:.1},M,{:.1},M,,",
            f.quality, f.sats, f.hdop, f.alt_msl, geoid_sep
        );
        sentence(&mut out, &gga);
        let mode = if f.quality == 2 { 'D' } else { 'A' };
        let date = format!("{:02}{:02}{:02}", start.day, start.month, start.year % 100);
        let rmc = format!(
            "GPRMC,{hms},A,{lat},{lon},{:.3},{:.2},{date},,,{mode}",
            f.speed_kn, f.course
        );
        sentence(&mut out, &rmc);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn checksum_matches_a_real_receiver_sentence() {
        // From gpsd's regression log of a MediaTek MT3339 (shared/data/nmea/mt3339.log).
        let body = "GPGGA,202640.000,4404.1306,N,12118.8515,W,2,10,0.98,1127.7,M,-19.6,M,0000,0000";
        assert_eq!(checksum(body), 0x6C);
    }

    #[test]
    fn angles_format_like_receivers() {
        assert_eq!(nmea_angle(44.068843333, true), "4404.13060,N");
        assert_eq!(nmea_angle(-121.314191667, false), "12118.85150,W");
        assert_eq!(nmea_angle(-0.999999999, true), "0100.00000,S");
    }

    #[test]
    fn log_is_crlf_checksummed_and_noise_has_the_requested_spread() {
        let m = GpsModel {
            bias_sigma: 0.0,
            noise_sigma: 5.0,
            tau_s: 1.0,
            duration_s: 3000,
            quality: 1,
            hdop: (0.9, 1.5),
            sats: (7, 12),
        };
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        // A local tangent-plane stand-in for the projection: 1e-5 degree per metre.
        let fixes = track(&mut rng, [0.0, 0.0, 250.0], &m, |x, y| {
            Ok((42.0 + y * 1e-5, -83.0 + x * 1e-5))
        })
        .unwrap();
        let var = fixes
            .iter()
            .map(|f| ((f.lat - 42.0) * 1e5).powi(2))
            .sum::<f64>()
            / fixes.len() as f64;
        assert!((var.sqrt() - 5.0).abs() < 0.6, "σ {}", var.sqrt());
        let text = nmea_log(
            &fixes[..40],
            &UtcStart {
                year: 2026,
                month: 6,
                day: 15,
                sec_of_day: 50000,
            },
            -34.5,
        );
        let lines: Vec<&str> = text.split_inclusive("\r\n").collect();
        assert_eq!(lines.len(), 80);
        for l in lines {
            assert!(l.ends_with("\r\n") && !l[..l.len() - 2].contains('\n'));
            let (body, cs) = l[1..l.len() - 2].split_once('*').unwrap();
            assert_eq!(u8::from_str_radix(cs, 16).unwrap(), checksum(body));
            let n = body.split(',').count();
            assert!(
                if body.starts_with("GPGGA") {
                    n == 15
                } else {
                    n == 13
                },
                "{body}"
            );
        }
        assert!(text.starts_with("$GPGGA,135320.00,"));
    }
}
