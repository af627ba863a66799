//! The sun over one day at the scene's site: when a multi-time scene (`simulate --times K`) is
//! captured, and where the sun stands at each time. A node stays where it is and sees the same
//! road at every hour; what changes between its captures is the light (shadows move with the
//! sun) and the traffic, which is what this module's times are for.
//!
//! The sun's position is the textbook approximation (declination from the day of the year,
//! local solar time from the longitude, no equation of time): within a degree or two of an
//! ephemeris, enough for plausible shadows.

use super::error::SimError;
use crate::error::Result;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use std::f64::consts::TAU;

/// Most times of day a scene is rendered at.
pub const MAX_TIMES: u32 = 24;
/// Sun elevations of an ordinary day's captures, degrees: the range a single capture draws its
/// sun from, so shadows stay shorter than the scene.
const DAY_EL_DEG: (f64, f64) = (18.0, 65.0);
/// Sun elevations of a low-sun day, degrees: long shadows at every time (the gantry's range).
pub(crate) const LOW_EL_DEG: (f64, f64) = (8.0, 25.0);
/// Latest capture, UTC seconds of the day: the GPS log of the first capture must not cross
/// midnight.
const LATEST_UTC_S: u32 = 22 * 3600;

/// One capture of the day.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Moment {
    /// UTC seconds of the day.
    pub sec_of_day: u32,
    /// Sun azimuth (clockwise from north) and elevation, degrees.
    pub sun_az_el_deg: [f64; 2],
}

/// The day of the captures and their times.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Day {
    /// Year, month (1..=12), day (1..=28).
    pub date: (u32, u32, u32),
    /// The captures, in time order.
    pub moments: Vec<Moment>,
}

/// Solar declination on day `doy` of the year (1 = 1 January), degrees.
fn declination_deg(doy: u32) -> f64 {
    -23.44 * (TAU * (doy as f64 + 10.0) / 365.0).cos()
}

/// Day of the year of `month`/`day` in a non-leap year.
fn day_of_year(month: u32, day: u32) -> u32 {
    const START: [u32; 12] = [0, 31, 59, 90, 120, 151, 181, 212, 243, 273, 304, 334];
    START[(month.clamp(1, 12) - 1) as usize] + day
}

/// Sun azimuth (clockwise from north) and elevation, degrees, at latitude `lat_deg` for solar
/// declination `decl_deg` and hour angle `hour_deg` (0 at local solar noon, 15° an hour, positive
/// in the afternoon).
pub(crate) fn sun_az_el(lat_deg: f64, decl_deg: f64, hour_deg: f64) -> [f64; 2] {
    let (lat, decl, h) = (
        lat_deg.to_radians(),
        decl_deg.to_radians(),
        hour_deg.to_radians(),
    );
    let el = (lat.sin() * decl.sin() + lat.cos() * decl.cos() * h.cos()).asin();
    // Azimuth from south, positive westward, then turned to clockwise from north.
    let from_south = h.sin().atan2(h.cos() * lat.sin() - decl.tan() * lat.cos());
    [
        (from_south.to_degrees() + 180.0).rem_euclid(360.0),
        el.to_degrees(),
    ]
}

/// `k` captures on one day at (`lat_deg`, `lon_deg`), drawn from `rng`: an April–October day
/// with the sun 18–65° up, or with `low_sun` a day around the winter solstice with it 8–25° up
/// at every capture. The captures spread over the hours the sun is in range: the day's eligible
/// minutes are cut into `k` equal parts and one time drawn from the middle half of each, so
/// consecutive captures are far apart and their shadows differ.
pub(crate) fn day(
    rng: &mut ChaCha8Rng,
    lat_deg: f64,
    lon_deg: f64,
    k: u32,
    low_sun: bool,
) -> Result<Day> {
    if k == 0 || k > MAX_TIMES {
        return Err(SimError::Count {
            flag: "--times",
            value: k,
            max: MAX_TIMES,
        }
        .into());
    }
    let year = 2026;
    let (month, dom, (lo, hi)) = if low_sun {
        // 8 December – 4 January: the noon sun stays below 25° at the site's latitude.
        let n = rng.random_range(0..28u32);
        let (m, d) = if n < 24 { (12, 8 + n) } else { (1, n - 23) };
        (m, d.min(28), LOW_EL_DEG)
    } else {
        (
            rng.random_range(4..=10),
            rng.random_range(1..=28),
            DAY_EL_DEG,
        )
    };
    let decl = declination_deg(day_of_year(month, dom));
    let eligible: Vec<(u32, [f64; 2])> = (0..LATEST_UTC_S / 60)
        .filter_map(|minute| {
            let solar_h = minute as f64 / 60.0 + lon_deg / 15.0;
            let s = sun_az_el(lat_deg, decl, 15.0 * (solar_h - 12.0));
            (lo..=hi).contains(&s[1]).then_some((minute, s))
        })
        .collect();
    let n = eligible.len();
    if n < 4 * k as usize {
        return Err(SimError::FewSunMinutes {
            lo,
            hi,
            minutes: n,
            times: k,
        }
        .into());
    }
    let part = n as f64 / k as f64;
    let moments = (0..k)
        .map(|i| {
            let at = (i as f64 + rng.random_range(0.25..0.75)) * part;
            let (minute, on_the_minute) = eligible[(at as usize).min(n - 1)];
            let sec_of_day = minute * 60 + rng.random_range(0..60);
            let solar_h = sec_of_day as f64 / 3600.0 + lon_deg / 15.0;
            let s = sun_az_el(lat_deg, decl, 15.0 * (solar_h - 12.0));
            // The seconds past the minute must not carry the sun out of range.
            if (lo..=hi).contains(&s[1]) {
                Moment {
                    sec_of_day,
                    sun_az_el_deg: s,
                }
            } else {
                Moment {
                    sec_of_day: minute * 60,
                    sun_az_el_deg: on_the_minute,
                }
            }
        })
        .collect();
    Ok(Day {
        date: (year, month, dom),
        moments,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn noon_sun_stands_south_at_the_complement_of_latitude_minus_declination() {
        let [az, el] = sun_az_el(42.3, -23.44, 0.0);
        assert!((az - 180.0).abs() < 1e-9, "{az}");
        assert!((el - (90.0 - 42.3 - 23.44)).abs() < 1e-9, "{el}");
        // Morning sun in the east half, afternoon in the west.
        assert!(sun_az_el(42.3, 10.0, -45.0)[0] < 180.0);
        assert!(sun_az_el(42.3, 10.0, 45.0)[0] > 180.0);
    }

    #[test]
    fn a_low_sun_day_stays_low_and_spreads_its_captures() {
        for seed in 0..20 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let d = day(&mut rng, 42.28, -83.74, 6, true).unwrap();
            assert_eq!(d.moments.len(), 6);
            for m in &d.moments {
                let el = m.sun_az_el_deg[1];
                assert!((LOW_EL_DEG.0..=LOW_EL_DEG.1).contains(&el), "{el}");
            }
            for w in d.moments.windows(2) {
                assert!(w[1].sec_of_day >= w[0].sec_of_day + 1800, "{w:?}");
            }
        }
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        assert!(day(&mut rng, 42.28, -83.74, 0, false).is_err());
        assert!(day(&mut rng, 42.28, -83.74, MAX_TIMES + 1, false).is_err());
    }
}
