//! The position prior: a robust, quality-weighted average of the fixes of a time window, or the
//! configured surveyed position when there are none. Pure: the caller feeds fixes and decides
//! when to stop waiting (the I/O shell owns the clock).
//!
//! Method (documented in `docs/gnss.md`):
//! 1. Keep one fix per epoch (the last one: it carries the most merged fields), of usable quality
//!    (GPS, DGPS, PPS, RTK fixed/float; not estimated/manual/simulated), with HDOP ≤ `max_hdop`,
//!    inside the last `window_s` seconds of receiver time.
//! 2. Per-fix 1-σ horizontal error: `σᵢ = HDOP · UERE(quality)` (HDOP 1 when absent).
//! 3. Outliers: local east/north metres about the component-wise median; a fix whose distance from
//!    the median exceeds `OUTLIER_K · max(1.4826 · MAD, MAD_FLOOR_M)` is rejected.
//! 4. The estimate is the `1/σᵢ²`-weighted mean of the rest. Its reported σ is
//!    `sqrt(scatter² + σ_fix²)`, where scatter is the weighted RMS distance from the mean and σ_fix
//!    the weighted-RMS per-fix σ — *not* divided by √n, because GNSS errors are strongly correlated
//!    over a window of seconds to minutes, so averaging does not shrink them like white noise.

use super::epoch::Fix;
use super::nmea::quality;
use serde::Serialize;
use std::collections::VecDeque;

/// Mean Earth radius, metres (local tangent-plane scale; the prior needs metres, not millimetres).
const EARTH_RADIUS_M: f64 = 6_371_008.8;
/// Outlier threshold in robust per-axis standard deviations. For 2-D Gaussian errors the radial
/// distance is Rayleigh-distributed and P(r > 3.5σ) = exp(−3.5²/2) ≈ 0.2 %.
pub(crate) const OUTLIER_K: f64 = 3.5;
/// Median of a Rayleigh distribution in units of its per-axis σ: √(2 ln 2).
const RAYLEIGH_MEDIAN_PER_SIGMA: f64 = 1.177_410_022_515_474_6;
/// Lower bound of the robust scale, metres: fixes quantised to 1e-4′ (0.18 m) or an RTK cluster
/// with MAD 0 must not reject their neighbours one quantum away.
pub(crate) const MAD_FLOOR_M: f64 = 0.5;
/// Fixes kept at most (10 Hz for 1000 s): bounds memory for any window setting.
const MAX_FIXES: usize = 10_000;
/// Milliseconds per day, for window ages across midnight when dates are unknown.
const MS_PER_DAY: f64 = 86_400_000.0;

/// User-equivalent range error per unit HDOP for a fix quality, metres (1 σ, horizontal); `None`
/// for qualities that are not a measurement (estimated, manual, simulated).
pub fn uere_m(q: u8) -> Option<f64> {
    match q {
        quality::GPS | quality::PPS => Some(3.0),
        quality::DGPS => Some(1.0),
        quality::RTK_FLOAT => Some(0.3),
        quality::RTK_FIXED => Some(0.03),
        _ => None,
    }
}

/// Settings of the prior (from `[gps]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PriorSettings {
    /// Window, seconds of receiver time back from the newest fix.
    pub window_s: f64,
    /// Fixes with a worse HDOP are ignored.
    pub max_hdop: f64,
    /// Accepted fixes needed for a GNSS estimate.
    pub min_fixes: usize,
}

/// A position estimate.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PriorEstimate {
    /// Latitude, degrees.
    pub lat: f64,
    /// Longitude, degrees.
    pub lon: f64,
    /// Weighted mean altitude above MSL, metres, if the fixes carried one.
    pub alt_msl: Option<f64>,
    /// 1-σ horizontal uncertainty, metres.
    pub sigma_m: f64,
    /// Fixes averaged.
    pub used: usize,
    /// Fixes rejected as outliers.
    pub rejected: usize,
}

/// Where the prior came from, and why (shown by `infraloc status`).
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "source", rename_all = "kebab-case")]
pub enum PriorOutcome {
    /// Averaged GNSS fixes.
    Gnss(PriorEstimate),
    /// The configured surveyed position; `reason` says why GNSS was not used.
    Fallback {
        /// Latitude, degrees.
        lat: f64,
        /// Longitude, degrees.
        lon: f64,
        /// Configured σ, metres.
        sigma_m: f64,
        /// Why GNSS was not used.
        reason: String,
    },
    /// The configured position (`[gps] source = "fixed"`): no receiver by design.
    Fixed {
        /// Latitude, degrees.
        lat: f64,
        /// Longitude, degrees.
        lon: f64,
        /// Configured σ, metres.
        sigma_m: f64,
    },
    /// No fix and no fallback configured.
    None {
        /// Why.
        reason: String,
    },
}

impl PriorOutcome {
    /// `(lat, lon, sigma_m)` if there is a position.
    pub fn position(&self) -> Option<(f64, f64, f64)> {
        match self {
            PriorOutcome::Gnss(e) => Some((e.lat, e.lon, e.sigma_m)),
            PriorOutcome::Fallback {
                lat, lon, sigma_m, ..
            }
            | PriorOutcome::Fixed { lat, lon, sigma_m } => Some((*lat, *lon, *sigma_m)),
            PriorOutcome::None { .. } => None,
        }
    }
}

#[derive(Debug, Clone, Copy)]
struct Sample {
    /// Receiver time, ms (absolute when dated, else time of day).
    t_ms: f64,
    dated: bool,
    epoch_key: (Option<super::nmea::Date>, u32),
    lat: f64,
    lon: f64,
    alt: Option<f64>,
    sigma: f64,
}

/// Accumulates fixes and computes the estimate.
#[derive(Debug, Clone)]
pub struct PriorEstimator {
    settings: PriorSettings,
    samples: VecDeque<Sample>,
    ignored: usize,
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

impl PriorEstimator {
    /// An empty estimator.
    pub fn new(settings: PriorSettings) -> Self {
        PriorEstimator {
            settings,
            samples: VecDeque::new(),
            ignored: 0,
        }
    }

    #[cfg(test)]
    /// Fixes ignored so far for quality, HDOP or missing time.
    pub(crate) fn ignored(&self) -> usize {
        self.ignored
    }

    /// Offer a fix. Returns whether it was kept.
    pub fn push(&mut self, f: &Fix) -> bool {
        let (Some(t), Some(uere)) = (f.time, uere_m(f.quality)) else {
            self.ignored += 1;
            return false;
        };
        let hdop = f.hdop.unwrap_or(1.0);
        let usable =
            hdop > 0.0 && hdop <= self.settings.max_hdop && f.lat.is_finite() && f.lon.is_finite();
        if !usable {
            self.ignored += 1;
            return false;
        }
        let (t_ms, dated) = match f.unix_time() {
            Some(u) => (u * 1000.0, true),
            None => (t.ms_of_day() as f64, false),
        };
        let s = Sample {
            t_ms,
            dated,
            epoch_key: (f.date, t.ms_of_day()),
            lat: f.lat,
            lon: f.lon,
            alt: f.alt_msl,
            sigma: hdop * uere,
        };
        // One sample per epoch: a later sentence of the same epoch replaces the earlier one.
        if let Some(last) = self.samples.back_mut() {
            if last.epoch_key.1 == s.epoch_key.1
                && (last.epoch_key.0 == s.epoch_key.0
                    || s.epoch_key.0.is_none()
                    || last.epoch_key.0.is_none())
            {
                *last = s;
                return true;
            }
        }
        self.samples.push_back(s);
        if self.samples.len() > MAX_FIXES {
            self.samples.pop_front();
        }
        true
    }

    /// Samples inside the window ending at the newest one.
    fn window(&self) -> Vec<Sample> {
        let Some(newest) = self.samples.back() else {
            return Vec::new();
        };
        let win_ms = self.settings.window_s * 1000.0;
        self.samples
            .iter()
            .filter(|s| {
                let mut age = newest.t_ms - s.t_ms;
                if !(s.dated && newest.dated) {
                    // Times of day only: compare modulo one day.
                    age = (newest.epoch_key.1 as f64 - s.epoch_key.1 as f64).rem_euclid(MS_PER_DAY);
                }
                (0.0..=win_ms).contains(&age)
            })
            .copied()
            .collect()
    }

    /// The robust weighted estimate, `None` with fewer than `min_fixes` accepted fixes.
    pub(crate) fn estimate(&self) -> Option<PriorEstimate> {
        let w = self.window();
        if w.is_empty() {
            return None;
        }
        let mut lats: Vec<f64> = w.iter().map(|s| s.lat).collect();
        let mut lons: Vec<f64> = w.iter().map(|s| s.lon).collect();
        let (lat0, lon0) = (median(&mut lats), median(&mut lons));
        let m_per_deg_n = EARTH_RADIUS_M.to_radians();
        let m_per_deg_e = m_per_deg_n * lat0.to_radians().cos();
        // Longitude differences wrap at the antimeridian.
        let en = |s: &Sample| {
            let dlon = (s.lon - lon0 + 540.0).rem_euclid(360.0) - 180.0;
            (dlon * m_per_deg_e, (s.lat - lat0) * m_per_deg_n)
        };
        let mut dist: Vec<f64> = w
            .iter()
            .map(|s| {
                let (e, n) = en(s);
                e.hypot(n)
            })
            .collect();
        let mad = median(&mut dist.clone());
        let scale = (mad / RAYLEIGH_MEDIAN_PER_SIGMA).max(MAD_FLOOR_M);
        let limit = OUTLIER_K * scale;
        let kept: Vec<(f64, f64, &Sample)> = w
            .iter()
            .zip(dist.iter_mut())
            .filter(|(_, d)| **d <= limit)
            .map(|(s, _)| {
                let (e, n) = en(s);
                (e, n, s)
            })
            .collect();
        if kept.len() < self.settings.min_fixes.max(1) {
            return None;
        }
        let wsum: f64 = kept.iter().map(|(_, _, s)| 1.0 / (s.sigma * s.sigma)).sum();
        let (mut me, mut mn) = (0.0, 0.0);
        for (e, n, s) in &kept {
            let wi = 1.0 / (s.sigma * s.sigma);
            me += wi * e;
            mn += wi * n;
        }
        me /= wsum;
        mn /= wsum;
        let scatter2 = kept
            .iter()
            .map(|(e, n, s)| ((e - me).powi(2) + (n - mn).powi(2)) / (s.sigma * s.sigma))
            .sum::<f64>()
            / wsum;
        let sigma_fix2 = kept.len() as f64 / wsum;
        let alts: Vec<(f64, f64)> = kept
            .iter()
            .filter_map(|(_, _, s)| s.alt.map(|a| (a, 1.0 / (s.sigma * s.sigma))))
            .collect();
        let alt_msl = (!alts.is_empty()).then(|| {
            alts.iter().map(|(a, w)| a * w).sum::<f64>() / alts.iter().map(|(_, w)| w).sum::<f64>()
        });
        Some(PriorEstimate {
            lat: lat0 + mn / m_per_deg_n,
            lon: ((lon0 + me / m_per_deg_e) + 540.0).rem_euclid(360.0) - 180.0,
            alt_msl,
            sigma_m: (scatter2 + sigma_fix2).sqrt(),
            used: kept.len(),
            rejected: w.len() - kept.len(),
        })
    }

    /// The final decision: the GNSS estimate if there is one, else the fallback with a reason.
    /// `why_no_fix` describes the source's state (e.g. "no fix after 120 s on /dev/ttyACM0").
    pub fn outcome(&self, fallback: Option<([f64; 2], f64)>, why_no_fix: &str) -> PriorOutcome {
        if let Some(e) = self.estimate() {
            return PriorOutcome::Gnss(e);
        }
        let reason = format!(
            "{why_no_fix}; {} usable in the {} s window (need {}), {} left out for quality, HDOP or a missing time",
            plural(self.window().len(), "fix", "fixes"),
            self.settings.window_s,
            self.settings.min_fixes.max(1),
            self.ignored
        );
        match fallback {
            Some(([lat, lon], sigma_m)) => PriorOutcome::Fallback {
                lat,
                lon,
                sigma_m,
                reason,
            },
            None => PriorOutcome::None { reason },
        }
    }
}

fn plural(n: usize, one: &str, many: &str) -> String {
    format!("{n} {}", if n == 1 { one } else { many })
}

#[cfg(test)]
mod tests {
    use super::super::{epoch::EpochMerger, nmea};
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    const SETTINGS: PriorSettings = PriorSettings {
        window_s: 30.0,
        max_hdop: 10.0,
        min_fixes: 5,
    };

    /// GGA sentences around a true position with Gaussian-ish noise, plus outliers.
    fn synth(n: usize, noise_m: f64, outliers: &[usize], seed: u64) -> Vec<Fix> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (lat0, lon0) = (42.3, -83.7);
        let mut m = EpochMerger::new();
        let m_per_deg = EARTH_RADIUS_M.to_radians();
        (0..n)
            .map(|i| {
                // Sum of uniforms: bounded, roughly Gaussian, deterministic.
                let g = |r: &mut ChaCha8Rng| (0..6).map(|_| r.random::<f64>() - 0.5).sum::<f64>();
                let (mut dn, mut de) = (g(&mut rng) * noise_m, g(&mut rng) * noise_m);
                if outliers.contains(&i) {
                    dn += 80.0;
                    de -= 50.0;
                }
                let lat = lat0 + dn / m_per_deg;
                let lon = lon0 + de / (m_per_deg * lat0.to_radians().cos());
                let mut data = format!("GPGGA,12{:02}{:02}.00,", i / 60, i % 60);
                nmea::format_coord(&mut data, lat, true, 7);
                data.push(',');
                nmea::format_coord(&mut data, lon, false, 7);
                data.push_str(",1,9,1.0,250.0,M,-34.0,M,,");
                let mut line = String::new();
                nmea::finish_sentence(&mut line, &data);
                m.push(&nmea::parse(line.as_bytes()).unwrap()).unwrap()
            })
            .collect()
    }

    fn dist_m(lat: f64, lon: f64) -> f64 {
        let m = EARTH_RADIUS_M.to_radians();
        ((lat - 42.3) * m).hypot((lon + 83.7) * m * 42.3f64.to_radians().cos())
    }

    #[test]
    fn outliers_are_rejected_and_mean_is_close() {
        let fixes = synth(30, 2.0, &[3, 17, 25], 7);
        let mut p = PriorEstimator::new(SETTINGS);
        for f in &fixes {
            assert!(p.push(f));
        }
        let e = p.estimate().unwrap();
        assert_eq!((e.used, e.rejected), (27, 3));
        // 27 samples with per-axis σ = 2·sqrt(6/12) ≈ 1.41 m: the mean is within ~1 m.
        assert!(dist_m(e.lat, e.lon) < 1.0, "{e:?}");
        // Without rejection the 3 outliers (≈94 m off) would pull the mean ≈ 9 m away.
        assert!(
            e.sigma_m > 3.0 && e.sigma_m < 4.0,
            "σ = HDOP·UERE ⊕ scatter: {e:?}"
        );
        assert!((e.alt_msl.unwrap() - 250.0).abs() < 1e-9);
    }

    #[test]
    fn window_keeps_only_recent_epochs_and_one_fix_per_epoch() {
        let fixes = synth(100, 1.0, &[], 3);
        let mut p = PriorEstimator::new(SETTINGS);
        for f in &fixes {
            p.push(f);
            p.push(f); // a second sentence of the same epoch replaces, not adds
        }
        assert_eq!(
            p.estimate().unwrap().used,
            31,
            "30 s window at 1 Hz, both ends inclusive"
        );
    }

    #[test]
    fn weights_follow_quality_and_hdop() {
        let mut m = EpochMerger::new();
        let mut p = PriorEstimator::new(PriorSettings {
            min_fixes: 1,
            ..SETTINGS
        });
        // An RTK-fixed fix and a GPS fix 1 m north: the mean sits within 1 mm of the RTK fix.
        for l in [
            "GPGGA,120000.00,4218.0000000,N,08342.0000000,W,4,12,0.8,250.0,M,,M,,",
            "GPGGA,120001.00,4218.0005396,N,08342.0000000,W,1,12,0.8,250.0,M,,M,,",
            "GPGGA,120002.00,4218.1000000,N,08342.0000000,W,7,12,0.8,250.0,M,,M,,",
            "GPGGA,120003.00,4218.1000000,N,08342.0000000,W,1,12,25.0,250.0,M,,M,,",
        ] {
            let mut s = String::new();
            nmea::finish_sentence(&mut s, l);
            p.push(&m.push(&nmea::parse(s.as_bytes()).unwrap()).unwrap());
        }
        assert_eq!(
            p.ignored(),
            2,
            "manual quality and HDOP 25 > max are ignored"
        );
        let e = p.estimate().unwrap();
        assert_eq!(e.used, 2);
        assert!(dist_m(e.lat, e.lon) < 1e-3, "{e:?}");
    }

    #[test]
    fn fallback_with_reason_when_no_fix() {
        let p = PriorEstimator::new(SETTINGS);
        match p.outcome(
            Some(([42.0, -83.0], 5.0)),
            "no fix after 120 s on /dev/ttyACM0",
        ) {
            PriorOutcome::Fallback {
                lat,
                sigma_m,
                reason,
                ..
            } => {
                assert_eq!((lat, sigma_m), (42.0, 5.0));
                assert!(
                    reason.contains("no fix after 120 s") && reason.contains("0 fixes usable"),
                    "{reason}"
                );
            }
            o => panic!("{o:?}"),
        }
        assert!(matches!(p.outcome(None, "x"), PriorOutcome::None { .. }));
    }
}
