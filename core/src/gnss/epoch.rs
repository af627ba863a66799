//! Per-epoch merging: sentences of one receiver epoch (same UTC time of day) complement each
//! other; sentences of other epochs never do.
//!
//! One [`Fix`] is emitted per position-carrying sentence (GGA, RMC, GNS, GLL with a valid fix),
//! as soon as it arrives (no look-ahead, so a live reader adds no latency). Its position and
//! quality come from that sentence; altitude, satellites and HDOP come from it or from a GGA/GNS
//! *of the same time of day*; the date comes from an RMC/ZDA of the same epoch or, failing that,
//! from the last date seen, advanced across midnight when the time of day wraps. A few recent
//! epochs are remembered (fixed array, no allocation) because some receivers interleave
//! sentences of adjacent epochs (Garmin 48's GLL lags by one second).

use super::nmea::{quality, Body, Date, Sentence, UtcTime};
use serde::Serialize;

/// Epochs remembered for merging.
const EPOCH_SLOTS: usize = 4;
/// Milliseconds per day.
const MS_PER_DAY: i64 = 86_400_000;
/// A time of day this much earlier than the dated one means the day rolled over.
const HALF_DAY_MS: i64 = MS_PER_DAY / 2;

/// A position fix, merged from the sentences of its epoch.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fix {
    source: [u8; 5],
    /// Date, when known (from RMC/ZDA).
    pub date: Option<Date>,
    /// UTC time of day, when the sentence carries one.
    pub time: Option<UtcTime>,
    /// Latitude, degrees.
    pub lat: f64,
    /// Longitude, degrees.
    pub lon: f64,
    /// Altitude above MSL, metres.
    pub alt_msl: Option<f64>,
    /// GGA-style quality (1 GPS, 2 DGPS, 4 RTK fixed, 5 RTK float, …).
    pub quality: u8,
    /// Satellites used.
    pub sats: Option<u8>,
    /// HDOP.
    pub hdop: Option<f64>,
}

impl Fix {
    /// The sentence this fix came from, e.g. `GPGGA`.
    pub(crate) fn source_sentence(&self) -> &str {
        std::str::from_utf8(&self.source).unwrap_or("")
    }

    /// ISO 8601 UTC: `2019-04-12T00:39:56.000Z`; time-only `00:39:56.000Z` when the date is
    /// unknown; milliseconds only when the sentence carried a fraction.
    pub fn iso_time(&self) -> Option<String> {
        let t = self.time?;
        Some(match self.date {
            Some(d) => format!("{d}T{t}Z"),
            None => format!("{t}Z"),
        })
    }

    /// Seconds since 1970-01-01 UTC (leap second 60 counts as the next second's start, as POSIX
    /// does), if date and time are known.
    pub fn unix_time(&self) -> Option<f64> {
        let (d, t) = (self.date?, self.time?);
        Some(d.days_since_epoch() as f64 * 86_400.0 + t.ms_of_day() as f64 / 1000.0)
    }

    /// The `infraloc gps decode` JSON record (docs/interfaces.md, "Command line and exit codes").
    pub fn record(&self) -> FixRecord {
        FixRecord {
            time: self.iso_time(),
            lat: self.lat,
            lon: self.lon,
            alt_msl: self.alt_msl,
            quality: self.quality,
            sats: self.sats,
            hdop: self.hdop,
            source_sentence: self.source_sentence().to_string(),
        }
    }
}

/// JSON form of a fix: one line of `infraloc gps decode`.
#[derive(Debug, Clone, Serialize)]
pub struct FixRecord {
    /// ISO 8601 UTC time (see [`Fix::iso_time`]).
    pub time: Option<String>,
    /// Latitude, degrees.
    pub lat: f64,
    /// Longitude, degrees.
    pub lon: f64,
    /// Altitude above MSL, metres.
    pub alt_msl: Option<f64>,
    /// GGA-style quality.
    pub quality: u8,
    /// Satellites used.
    pub sats: Option<u8>,
    /// HDOP.
    pub hdop: Option<f64>,
    /// E.g. `GPGGA`.
    pub source_sentence: String,
}

#[derive(Debug, Clone, Copy, Default)]
struct Epoch {
    ms_of_day: u32,
    date: Option<Date>,
    alt_msl: Option<f64>,
    sats: Option<u8>,
    hdop: Option<f64>,
}

/// Counters of what the merger saw.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub(crate) struct MergeStats {
    /// Sentences consumed.
    pub sentences: u64,
    /// Fixes emitted.
    pub fixes: u64,
    /// Sentences that declared no fix (GGA quality 0, RMC/GLL `V`, GNS `N`).
    pub no_fix_sentences: u64,
}

/// The merger: feed parsed sentences in arrival order, get fixes.
#[derive(Debug, Clone, Default)]
pub struct EpochMerger {
    slots: [Option<Epoch>; EPOCH_SLOTS],
    next_slot: usize,
    /// Last date seen and the time of day it belonged to.
    last_date: Option<(Date, u32)>,
    stats: MergeStats,
}

impl EpochMerger {
    /// An empty merger.
    pub fn new() -> Self {
        Self::default()
    }

    /// Counters.
    pub(crate) fn stats(&self) -> MergeStats {
        self.stats
    }

    fn slot(&mut self, ms: u32) -> &mut Epoch {
        let idx = match self
            .slots
            .iter()
            .position(|s| s.is_some_and(|e| e.ms_of_day == ms))
        {
            Some(i) => i,
            None => {
                let i = self.next_slot;
                self.next_slot = (i + 1) % EPOCH_SLOTS;
                self.slots[i] = Some(Epoch {
                    ms_of_day: ms,
                    ..Epoch::default()
                });
                i
            }
        };
        // The slot was just found or filled, so it is `Some`.
        self.slots[idx].get_or_insert_with(Epoch::default)
    }

    /// The date that applies to a time of day, from the last dated sentence: the same day, or
    /// the next/previous one when the clock wrapped past midnight since.
    fn date_for(&self, ms: u32) -> Option<Date> {
        let (d, dated_ms) = self.last_date?;
        let dt = ms as i64 - dated_ms as i64;
        Some(if dt < -HALF_DAY_MS {
            d.succ()
        } else if dt > HALF_DAY_MS {
            d.pred()
        } else {
            d
        })
    }

    /// Consume one sentence; returns the fix it completes, if it carries a valid position.
    pub fn push(&mut self, s: &Sentence) -> Option<Fix> {
        self.stats.sentences += 1;
        let time = s.time();
        // Record what this sentence contributes to its epoch.
        if let Some(t) = time {
            let ms = t.ms_of_day();
            let own_date = match &s.body {
                Body::Rmc(r) => r.date,
                Body::Zda(z) => z.date,
                _ => None,
            };
            if let Some(d) = own_date {
                self.last_date = Some((d, ms));
            }
            let e = self.slot(ms);
            if own_date.is_some() {
                e.date = own_date;
            }
            match &s.body {
                Body::Gga(g) if g.quality != quality::INVALID => {
                    e.alt_msl = g.alt_msl.or(e.alt_msl);
                    e.sats = g.sats.or(e.sats);
                    e.hdop = g.hdop.or(e.hdop);
                }
                Body::Gns(g) if g.quality != quality::INVALID => {
                    e.alt_msl = g.alt_msl.or(e.alt_msl);
                    e.sats = g.sats.or(e.sats);
                    e.hdop = g.hdop.or(e.hdop);
                }
                _ => {}
            }
        }
        let is_fix_kind = matches!(
            s.body,
            Body::Gga(_) | Body::Rmc(_) | Body::Gns(_) | Body::Gll(_)
        );
        let Some((pos, q)) = s.position() else {
            if is_fix_kind {
                self.stats.no_fix_sentences += 1;
            }
            return None;
        };
        let mut source = [b'?'; 5];
        let a = s.address().as_bytes();
        source[..a.len().min(5)].copy_from_slice(&a[..a.len().min(5)]);
        let mut fix = Fix {
            source,
            date: None,
            time,
            lat: pos.lat,
            lon: pos.lon,
            alt_msl: None,
            quality: q,
            sats: None,
            hdop: None,
        };
        if let Some(t) = time {
            let ms = t.ms_of_day();
            let e = *self.slot(ms);
            fix.date = e.date.or_else(|| self.date_for(ms));
            fix.alt_msl = e.alt_msl;
            fix.sats = e.sats;
            fix.hdop = e.hdop;
        } else if let Body::Gga(g) = &s.body {
            // No time: nothing to merge with, but the sentence's own fields still count.
            (fix.alt_msl, fix.sats, fix.hdop) = (g.alt_msl, g.sats, g.hdop);
        } else if let Body::Gns(g) = &s.body {
            (fix.alt_msl, fix.sats, fix.hdop) = (g.alt_msl, g.sats, g.hdop);
        }
        self.stats.fixes += 1;
        Some(fix)
    }
}

#[cfg(test)]
mod tests {
    use super::super::nmea::parse;
    use super::*;

    fn run(lines: &[&str]) -> Vec<Fix> {
        let mut m = EpochMerger::new();
        lines
            .iter()
            .filter_map(|l| m.push(&parse(l.as_bytes()).unwrap()))
            .collect()
    }

    #[test]
    fn gga_gets_date_from_rmc_of_the_same_epoch_and_rmc_gets_altitude() {
        let f = run(&[
            "$GPGGA,120000.00,4552.65403,S,17030.00668,E,1,12,0.64,14.2,M,1.8,M,,",
            "$GPRMC,120000.00,A,4552.65403,S,17030.00668,E,0.0,,120419,,,A",
        ]);
        assert_eq!(f.len(), 2);
        // GGA came first: at that point no date is known.
        assert_eq!(f[0].iso_time().unwrap(), "12:00:00.000Z");
        assert_eq!(f[1].iso_time().unwrap(), "2019-04-12T12:00:00.000Z");
        assert_eq!(
            (f[1].alt_msl, f[1].sats, f[1].hdop),
            (Some(14.2), Some(12), Some(0.64))
        );
        assert_eq!(f[1].source_sentence(), "GPRMC");
    }

    #[test]
    fn stale_fields_of_an_earlier_epoch_are_never_used() {
        let f = run(&[
            "$GPGGA,120000.00,4552.65403,S,17030.00668,E,1,12,0.64,14.2,M,1.8,M,,",
            "$GPRMC,120000.00,A,4552.65403,S,17030.00668,E,0.0,,120419,,,A",
            "$GPRMC,120001.00,A,4552.65403,S,17030.00668,E,0.0,,120419,,,A",
            "$GPGGA,120002.00,4552.65403,S,17030.00668,E,1,,,,M,1.8,M,,",
        ]);
        assert_eq!((f[2].alt_msl, f[2].sats, f[2].hdop), (None, None, None));
        assert_eq!((f[3].alt_msl, f[3].sats, f[3].hdop), (None, None, None));
        // The date carries over (it changes only at midnight).
        assert_eq!(f[3].iso_time().unwrap(), "2019-04-12T12:00:02.000Z");
    }

    #[test]
    fn date_rolls_over_at_midnight_and_leap_second() {
        let f = run(&[
            "$GPRMC,235959,A,4552.65403,S,17030.00668,E,0.0,,311216,,,A",
            "$GPGGA,235960,4552.65403,S,17030.00668,E,1,8,1.0,14.2,M,1.8,M,,",
            "$GPGGA,000000,4552.65403,S,17030.00668,E,1,8,1.0,14.2,M,1.8,M,,",
        ]);
        assert_eq!(f[1].iso_time().unwrap(), "2016-12-31T23:59:60Z");
        assert_eq!(f[2].iso_time().unwrap(), "2017-01-01T00:00:00Z");
        assert_eq!(f[2].unix_time().unwrap(), 1_483_228_800.0);
    }

    #[test]
    fn no_fix_sentences_give_no_fix_but_are_counted() {
        let mut m = EpochMerger::new();
        for l in [
            "$GPGGA,102136.000,3340.8472,S,15117.3205,E,0,02,99.0,064.19,M,22.4,M,,*41",
            "$GPRMC,102136.000,V,3340.8472,S,15117.3205,E,0.0,0.0,251112,0.0,W*79",
        ] {
            assert!(m.push(&parse(l.as_bytes()).unwrap()).is_none());
        }
        assert_eq!(m.stats().no_fix_sentences, 2);
        assert_eq!(m.stats().fixes, 0);
    }
}
