//! Zero-allocation NMEA 0183 sentence parser: GGA, RMC, GNS, GLL and ZDA, any two-letter talker.
//!
//! Written here rather than taken from the `nmea` crate because that crate rejects second 60
//! (leap seconds, which receivers do emit) and allocates per sentence. The parser works on one
//! line as bytes (`$…*hh`, terminators already stripped by [`super::framing`]) and returns
//! plain `Copy` values; it never panics on any input (fuzzed, see `docs/fuzzing.md`).
//!
//! Decisions (see `docs/gnss.md`):
//! - Checksums are compared case-insensitively. A sentence *without* `*hh` is accepted, as
//!   gpsd does (some old receivers omit it); [`Sentence::checksum`] says whether one was present.
//! - Empty fields are `None`; a sentence whose fix fields are empty or that declares no fix
//!   (GGA quality 0, RMC/GLL status `V`, GNS mode all `N`) is parsed fine and simply yields no
//!   position ([`Sentence::position`] is `None`).
//! - An RMC whose date field is corrupt (`2208-1`) keeps its time and position and loses only the
//!   date ([`Rmc::date_dropped`]), as gpsd does; any other malformed field rejects the sentence.

use std::fmt;

/// Longest address field kept (`GPGGA` is 5; proprietary `PMTK001`, `PQVERNO` are longer, and
/// proprietary addresses beyond this are accepted but stored truncated).
const ADDRESS_MAX: usize = 8;
/// Milliseconds per second / minute / hour, for time-of-day arithmetic.
const MS_PER_S: u32 = 1000;
const MS_PER_MIN: u32 = 60 * MS_PER_S;
const MS_PER_H: u32 = 60 * MS_PER_MIN;
/// Two-digit RMC years below this pivot are 20yy, others 19yy (NMEA's 2-digit year).
const CENTURY_PIVOT: u16 = 80;

/// Why a line is not a usable sentence. Small and `Copy`: parsing never allocates.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NmeaError {
    /// The line does not start with `$` (or `!`).
    NoStart,
    /// The `*hh` checksum is malformed (not two hex digits, or data after them).
    BadChecksumSyntax,
    /// The checksum does not match the data.
    ChecksumMismatch {
        /// Checksum written in the sentence.
        given: u8,
        /// Checksum computed over the data.
        computed: u8,
    },
    /// The address field (`GPGGA`) is missing or malformed.
    BadAddress,
    /// An address with no data fields at all (e.g. a bare `$PQVERNO`); gpsd drops these too.
    NoFields,
    /// A field of a known sentence is malformed. `index` counts data fields from 1 (after the address).
    BadField {
        /// Field number (1 = first field after the address).
        index: u8,
        /// Which quantity.
        what: &'static str,
    },
}

impl fmt::Display for NmeaError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            NmeaError::NoStart => write!(f, "line does not start with '$'"),
            NmeaError::BadChecksumSyntax => write!(f, "malformed '*hh' checksum"),
            NmeaError::ChecksumMismatch { given, computed } => {
                write!(f, "checksum {given:02X} != computed {computed:02X}")
            }
            NmeaError::BadAddress => write!(f, "malformed address field"),
            NmeaError::NoFields => write!(f, "no data fields"),
            NmeaError::BadField { index, what } => write!(f, "field {index} ({what}) malformed"),
        }
    }
}

impl std::error::Error for NmeaError {}

/// UTC time of day as the receiver wrote it. `second` may be 60 (leap second).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct UtcTime {
    /// 0..=23
    pub hour: u8,
    /// 0..=59
    pub minute: u8,
    /// 0..=60 (60 only during a leap second)
    pub second: u8,
    /// 0..=999; fraction digits beyond milliseconds are truncated.
    pub millis: u16,
    /// Whether the sentence carried a fractional part (if not, `millis` is 0 and not printed).
    pub has_fraction: bool,
}

impl UtcTime {
    /// Milliseconds since 00:00:00 of the day (up to 86 400 999 during a leap second): the epoch key.
    pub fn ms_of_day(&self) -> u32 {
        self.hour as u32 * MS_PER_H
            + self.minute as u32 * MS_PER_MIN
            + self.second as u32 * MS_PER_S
            + self.millis as u32
    }
}

impl fmt::Display for UtcTime {
    /// `HH:MM:SS[.mmm]Z`-less core (`HH:MM:SS` plus `.mmm` when the sentence carried a fraction).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:02}:{:02}:{:02}", self.hour, self.minute, self.second)?;
        if self.has_fraction {
            write!(f, ".{:03}", self.millis)?;
        }
        Ok(())
    }
}

/// A calendar date (proleptic Gregorian, UTC).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Date {
    /// Full year, e.g. 2019.
    pub year: u16,
    /// 1..=12
    pub month: u8,
    /// 1..=31 (checked against the month)
    pub day: u8,
}

impl Date {
    /// Build a date, `None` if it does not exist.
    pub fn new(year: u16, month: u8, day: u8) -> Option<Date> {
        if (1..=12).contains(&month) && day >= 1 && day <= days_in_month(year, month) {
            Some(Date { year, month, day })
        } else {
            None
        }
    }

    /// Days since 1970-01-01 (negative before).
    pub fn days_since_epoch(&self) -> i64 {
        // Howard Hinnant's days_from_civil, shifted so that March is month 0.
        let y = self.year as i64 - i64::from(self.month <= 2);
        let era = y.div_euclid(400);
        let yoe = y - era * 400;
        let m = self.month as i64;
        let doy = (153 * (if m > 2 { m - 3 } else { m + 9 }) + 2) / 5 + self.day as i64 - 1;
        let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
        era * 146_097 + doe - 719_468
    }

    /// The next calendar day.
    pub(crate) fn succ(&self) -> Date {
        if self.day < days_in_month(self.year, self.month) {
            Date {
                day: self.day + 1,
                ..*self
            }
        } else if self.month < 12 {
            Date {
                month: self.month + 1,
                day: 1,
                ..*self
            }
        } else {
            Date {
                year: self.year.saturating_add(1),
                month: 1,
                day: 1,
            }
        }
    }

    /// The previous calendar day.
    pub(crate) fn pred(&self) -> Date {
        if self.day > 1 {
            Date {
                day: self.day - 1,
                ..*self
            }
        } else if self.month > 1 {
            let m = self.month - 1;
            Date {
                month: m,
                day: days_in_month(self.year, m),
                ..*self
            }
        } else {
            Date {
                year: self.year.saturating_sub(1),
                month: 12,
                day: 31,
            }
        }
    }
}

impl fmt::Display for Date {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:04}-{:02}-{:02}", self.year, self.month, self.day)
    }
}

fn is_leap(year: u16) -> bool {
    (year % 4 == 0 && year % 100 != 0) || year % 400 == 0
}

fn days_in_month(year: u16, month: u8) -> u8 {
    match month {
        2 if is_leap(year) => 29,
        2 => 28,
        4 | 6 | 9 | 11 => 30,
        _ => 31,
    }
}

/// Fix quality in GGA's numbering, which [`crate::gnss::Fix`] uses for every sentence type.
pub mod quality {
    /// No fix.
    pub(crate) const INVALID: u8 = 0;
    /// Autonomous GNSS fix.
    pub(crate) const GPS: u8 = 1;
    /// Differential (SBAS/DGPS).
    pub(crate) const DGPS: u8 = 2;
    /// PPS / precise.
    pub(crate) const PPS: u8 = 3;
    /// RTK, integer ambiguities fixed.
    pub(crate) const RTK_FIXED: u8 = 4;
    /// RTK, float ambiguities.
    pub(crate) const RTK_FLOAT: u8 = 5;
    /// Dead reckoning (estimated).
    pub(crate) const ESTIMATED: u8 = 6;
    /// Manually entered position.
    pub(crate) const MANUAL: u8 = 7;
    /// Simulator.
    pub(crate) const SIMULATION: u8 = 8;

    /// Map an NMEA 2.3+ mode indicator (RMC/GLL/GNS) to the GGA quality number.
    pub fn from_mode(mode: u8) -> u8 {
        match mode {
            b'A' => GPS,
            b'D' => DGPS,
            b'P' => PPS,
            b'R' => RTK_FIXED,
            b'F' => RTK_FLOAT,
            b'E' => ESTIMATED,
            b'M' => MANUAL,
            b'S' => SIMULATION,
            _ => INVALID, // 'N' and anything unknown
        }
    }
}

/// A latitude/longitude pair in degrees (WGS84 as the receiver reports it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LatLon {
    /// Degrees north, −90..=90.
    pub lat: f64,
    /// Degrees east, −180..=180.
    pub lon: f64,
}

/// GGA: time, position, quality, satellites, HDOP, altitude.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gga {
    /// UTC time of day.
    pub time: Option<UtcTime>,
    /// Position (absent if the fields are empty).
    pub pos: Option<LatLon>,
    /// Quality 0..=8 (0 = no fix).
    pub quality: u8,
    /// Satellites used.
    pub sats: Option<u8>,
    /// Horizontal dilution of precision.
    pub hdop: Option<f64>,
    /// Altitude above mean sea level, metres.
    pub alt_msl: Option<f64>,
    /// Geoid separation (ellipsoid − MSL), metres.
    pub geoid_sep: Option<f64>,
}

/// RMC: time, status, position, date, mode.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rmc {
    /// UTC time of day.
    pub time: Option<UtcTime>,
    /// Status `A` valid, `V` warning (no fix).
    pub valid: bool,
    /// Position.
    pub pos: Option<LatLon>,
    /// Date.
    pub date: Option<Date>,
    /// The date field was present but is not a `ddmmyy` date (receivers do send e.g. `2208-1`).
    /// Like gpsd, the sentence is kept without its date rather than thrown away, because its
    /// position is fine; [`crate::gnss::DecodeStats::dropped_dates`] counts these.
    pub date_dropped: bool,
    /// NMEA 2.3+ mode indicator (`A`, `D`, `R`, `N`, …), if present.
    pub mode: Option<u8>,
}

/// GNS: multi-constellation fix data.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gns {
    /// UTC time of day.
    pub time: Option<UtcTime>,
    /// Position.
    pub pos: Option<LatLon>,
    /// Best mode over the per-constellation mode characters, as a GGA quality.
    pub quality: u8,
    /// Satellites used.
    pub sats: Option<u8>,
    /// HDOP.
    pub hdop: Option<f64>,
    /// Altitude above MSL, metres.
    pub alt_msl: Option<f64>,
}

/// GLL: position, time, status.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gll {
    /// Position.
    pub pos: Option<LatLon>,
    /// UTC time of day (absent in NMEA 1.x GLL).
    pub time: Option<UtcTime>,
    /// Status `A` valid.
    pub valid: bool,
    /// Mode indicator (NMEA 2.3+).
    pub mode: Option<u8>,
}

/// ZDA: time and full date.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Zda {
    /// UTC time of day.
    pub time: Option<UtcTime>,
    /// Date (absent if any of day/month/year is empty).
    pub date: Option<Date>,
}

/// The parsed content of a sentence.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Body {
    /// GGA
    Gga(Gga),
    /// RMC
    Rmc(Rmc),
    /// GNS
    Gns(Gns),
    /// GLL
    Gll(Gll),
    /// ZDA
    Zda(Zda),
    /// Any other (valid-checksum) sentence; its content is not interpreted.
    Other,
}

/// Whether the sentence carried a checksum.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Checksum {
    /// `*hh` present and correct.
    Valid,
    /// No `*hh` at all (accepted, like gpsd).
    Absent,
}

/// One parsed sentence.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sentence {
    address: [u8; ADDRESS_MAX],
    address_len: u8,
    /// Checksum state.
    pub checksum: Checksum,
    /// Content.
    pub body: Body,
}

impl Sentence {
    /// The address field, e.g. `GPGGA` or `PGRME`.
    pub(crate) fn address(&self) -> &str {
        // The address is checked to be ASCII alphanumeric when parsed.
        std::str::from_utf8(&self.address[..self.address_len as usize]).unwrap_or("")
    }

    #[cfg(test)]
    /// Talker id (`GP`, `GN`, …; `P` for proprietary sentences).
    pub(crate) fn talker(&self) -> &str {
        let a = self.address();
        if a.starts_with('P') {
            "P"
        } else {
            a.get(..2).unwrap_or("")
        }
    }

    /// UTC time of day if the sentence carries one.
    pub fn time(&self) -> Option<UtcTime> {
        match &self.body {
            Body::Gga(s) => s.time,
            Body::Rmc(s) => s.time,
            Body::Gns(s) => s.time,
            Body::Gll(s) => s.time,
            Body::Zda(s) => s.time,
            Body::Other => None,
        }
    }

    /// The position and its GGA-style quality if this sentence reports a valid fix.
    pub fn position(&self) -> Option<(LatLon, u8)> {
        match &self.body {
            Body::Gga(s) if s.quality != quality::INVALID => s.pos.map(|p| (p, s.quality)),
            Body::Gns(s) if s.quality != quality::INVALID => s.pos.map(|p| (p, s.quality)),
            Body::Rmc(Rmc {
                valid: true,
                pos: Some(p),
                mode,
                ..
            })
            | Body::Gll(Gll {
                valid: true,
                pos: Some(p),
                mode,
                ..
            }) => {
                // Before NMEA 2.3 there is no mode: status A means an autonomous fix.
                let q = mode.map_or(quality::GPS, quality::from_mode);
                (q != quality::INVALID).then_some((*p, q))
            }
            _ => None,
        }
    }
}

/// XOR of the bytes between `$` and `*`: the NMEA checksum.
pub(crate) fn checksum(data: &[u8]) -> u8 {
    data.iter().fold(0u8, |a, &b| a ^ b)
}

fn hex_digit(b: u8) -> Option<u8> {
    match b {
        b'0'..=b'9' => Some(b - b'0'),
        b'A'..=b'F' => Some(b - b'A' + 10),
        b'a'..=b'f' => Some(b - b'a' + 10),
        _ => None,
    }
}

/// Comma-separated fields over a byte slice, without allocation.
struct Fields<'a> {
    rest: Option<&'a [u8]>,
    index: u8,
}

impl<'a> Fields<'a> {
    /// Next field (empty slice once the sentence has run out, so trailing fields read as empty).
    fn next(&mut self) -> (&'a [u8], u8) {
        self.index = self.index.saturating_add(1);
        let idx = self.index;
        match self.rest {
            None => (&[], idx),
            Some(r) => match r.iter().position(|&b| b == b',') {
                Some(i) => {
                    self.rest = Some(&r[i + 1..]);
                    (&r[..i], idx)
                }
                None => {
                    self.rest = None;
                    (r, idx)
                }
            },
        }
    }

    fn skip(&mut self, n: usize) {
        for _ in 0..n {
            self.next();
        }
    }
}

/// Powers of ten exactly representable in f64: the fast path of decimal parsing.
const POW10: [f64; 23] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16,
    1e17, 1e18, 1e19, 1e20, 1e21, 1e22,
];
/// Largest integer mantissa for which `m / 10^k` is correctly rounded (2^53).
const EXACT_MANTISSA: u64 = 1 << 53;

/// Digits of an unsigned decimal `int[.frac]`: (integer part, fraction digits value, fraction digit count).
/// `None` for anything else or if the integer part overflows u64. Fraction digits beyond 19 are
/// dropped by the callers' precision anyway; we cap the count and keep parsing validation.
fn split_decimal(f: &[u8]) -> Option<(u64, u64, u32)> {
    let mut int: u64 = 0;
    let mut frac: u64 = 0;
    let mut nfrac: u32 = 0;
    let mut seen_dot = false;
    let mut ndigits = 0usize;
    for &b in f {
        match b {
            b'0'..=b'9' => {
                let d = (b - b'0') as u64;
                ndigits += 1;
                if seen_dot {
                    // Keep at most 18 fraction digits; further ones are below any useful precision.
                    if nfrac < 18 {
                        frac = frac * 10 + d;
                        nfrac += 1;
                    }
                } else {
                    int = int.checked_mul(10)?.checked_add(d)?;
                }
            }
            b'.' if !seen_dot => seen_dot = true,
            _ => return None,
        }
    }
    (ndigits > 0).then_some((int, frac, nfrac))
}

/// Parse a plain decimal number (`-12.5`, `0.64`, `064.19`) with no allocation. Exact (correctly
/// rounded) when the digits fit 2^53 and there are ≤ 22 fraction digits, else via `str::parse`.
pub(crate) fn parse_decimal(f: &[u8]) -> Option<f64> {
    let (neg, body) = match f.first() {
        Some(b'-') => (true, &f[1..]),
        Some(b'+') => (false, &f[1..]),
        _ => (false, f),
    };
    let (int, frac, nfrac) = split_decimal(body)?;
    let pow = POW10.get(nfrac as usize).copied()?;
    let mantissa = int
        .checked_mul(pow as u64)
        .and_then(|m| m.checked_add(frac))
        .filter(|&m| m <= EXACT_MANTISSA);
    let v = match mantissa {
        Some(m) => m as f64 / pow,
        // Rare: too many digits for the exact fast path; let core do correct rounding.
        None => std::str::from_utf8(body).ok()?.parse::<f64>().ok()?,
    };
    Some(if neg { -v } else { v })
}

fn parse_u8(f: &[u8]) -> Option<u8> {
    if f.is_empty() || f.len() > 3 {
        return None;
    }
    let mut v: u16 = 0;
    for &b in f {
        if !b.is_ascii_digit() {
            return None;
        }
        v = v * 10 + (b - b'0') as u16;
    }
    u8::try_from(v).ok()
}

fn two_digits(f: &[u8]) -> Option<u8> {
    match f {
        [a @ b'0'..=b'9', b @ b'0'..=b'9', ..] => Some((a - b'0') * 10 + (b - b'0')),
        _ => None,
    }
}

/// `hhmmss[.f…]`; second 60 accepted (leap second).
fn parse_time(f: &[u8]) -> Option<UtcTime> {
    if f.len() < 6 {
        return None;
    }
    let hour = two_digits(&f[0..2])?;
    let minute = two_digits(&f[2..4])?;
    let second = two_digits(&f[4..6])?;
    if hour > 23 || minute > 59 || second > 60 {
        return None;
    }
    let (millis, has_fraction) = match &f[6..] {
        [] => (0, false),
        [b'.', digits @ ..] => {
            if !digits.iter().all(u8::is_ascii_digit) {
                return None;
            }
            // Truncate to milliseconds: rounding could carry into the next second.
            let mut ms: u16 = 0;
            for i in 0..3 {
                ms = ms * 10 + digits.get(i).map_or(0, |d| (d - b'0') as u16);
            }
            (ms, true)
        }
        _ => return None,
    };
    Some(UtcTime {
        hour,
        minute,
        second,
        millis,
        has_fraction,
    })
}

/// `ddmmyy` (RMC).
fn parse_date6(f: &[u8]) -> Option<Date> {
    if f.len() != 6 {
        return None;
    }
    let day = two_digits(&f[0..2])?;
    let month = two_digits(&f[2..4])?;
    let yy = two_digits(&f[4..6])? as u16;
    let year = if yy < CENTURY_PIVOT {
        2000 + yy
    } else {
        1900 + yy
    };
    Date::new(year, month, day)
}

/// `(d)ddmm.mmmm` + hemisphere → signed degrees. Degrees and minutes are split on the integer
/// digits so the minutes keep all their decimals (matches gpsd to ~1e-14°).
fn parse_coord(v: &[u8], hemi: &[u8], max_deg: u64, pos: u8, neg: u8) -> Result<Option<f64>, ()> {
    if v.is_empty() && hemi.is_empty() {
        return Ok(None);
    }
    let (int, frac, nfrac) = split_decimal(v).ok_or(())?;
    let deg = int / 100;
    let min_int = int % 100;
    if deg > max_deg || min_int >= 60 {
        return Err(());
    }
    let minutes = min_int as f64 + frac as f64 / POW10[nfrac as usize];
    let value = deg as f64 + minutes / 60.0;
    if value > max_deg as f64 {
        return Err(());
    }
    match hemi {
        [h] if *h == pos => Ok(Some(value)),
        [h] if *h == neg => Ok(Some(-value)),
        _ => Err(()),
    }
}

fn opt<T>(
    f: &[u8],
    idx: u8,
    what: &'static str,
    p: impl Fn(&[u8]) -> Option<T>,
) -> Result<Option<T>, NmeaError> {
    if f.is_empty() {
        Ok(None)
    } else {
        p(f).map(Some)
            .ok_or(NmeaError::BadField { index: idx, what })
    }
}

fn latlon(fs: &mut Fields<'_>) -> Result<Option<LatLon>, NmeaError> {
    let (lat, i_lat) = fs.next();
    let (ns, _) = fs.next();
    let (lon, i_lon) = fs.next();
    let (ew, _) = fs.next();
    let lat = parse_coord(lat, ns, 90, b'N', b'S').map_err(|_| NmeaError::BadField {
        index: i_lat,
        what: "latitude",
    })?;
    let lon = parse_coord(lon, ew, 180, b'E', b'W').map_err(|_| NmeaError::BadField {
        index: i_lon,
        what: "longitude",
    })?;
    Ok(match (lat, lon) {
        (Some(lat), Some(lon)) => Some(LatLon { lat, lon }),
        _ => None,
    })
}

fn status(f: &[u8], idx: u8) -> Result<bool, NmeaError> {
    match f {
        b"A" => Ok(true),
        b"V" | b"" => Ok(false),
        _ => Err(NmeaError::BadField {
            index: idx,
            what: "status",
        }),
    }
}

fn mode_char(f: &[u8], idx: u8) -> Result<Option<u8>, NmeaError> {
    match f {
        [] => Ok(None),
        [c] if c.is_ascii_uppercase() => Ok(Some(*c)),
        _ => Err(NmeaError::BadField {
            index: idx,
            what: "mode",
        }),
    }
}

fn parse_gga(fs: &mut Fields<'_>) -> Result<Gga, NmeaError> {
    let (t, it) = fs.next();
    let time = opt(t, it, "time", parse_time)?;
    let pos = latlon(fs)?;
    let (q, iq) = fs.next();
    let quality = opt(q, iq, "quality", |f| {
        parse_u8(f).filter(|&q| q <= quality::SIMULATION)
    })?
    .unwrap_or(quality::INVALID);
    let (s, is) = fs.next();
    let sats = opt(s, is, "satellites", parse_u8)?;
    let (h, ih) = fs.next();
    let hdop = opt(h, ih, "hdop", parse_decimal)?;
    let (a, ia) = fs.next();
    let alt_msl = opt(a, ia, "altitude", parse_decimal)?;
    fs.skip(1); // altitude unit, always M
    let (g, ig) = fs.next();
    let geoid_sep = opt(g, ig, "geoid separation", parse_decimal)?;
    Ok(Gga {
        time,
        pos,
        quality,
        sats,
        hdop,
        alt_msl,
        geoid_sep,
    })
}

fn parse_rmc(fs: &mut Fields<'_>) -> Result<Rmc, NmeaError> {
    let (t, it) = fs.next();
    let time = opt(t, it, "time", parse_time)?;
    let (s, is) = fs.next();
    let valid = status(s, is)?;
    let pos = latlon(fs)?;
    fs.skip(2); // speed, course
    let (d, _) = fs.next();
    // A corrupt date drops the date only (see `Rmc::date_dropped`).
    let date = parse_date6(d);
    let date_dropped = !d.is_empty() && date.is_none();
    fs.skip(2); // magnetic variation, E/W
    let (m, im) = fs.next();
    let mode = mode_char(m, im)?;
    Ok(Rmc {
        time,
        valid,
        pos,
        date,
        date_dropped,
        mode,
    })
}

fn parse_gns(fs: &mut Fields<'_>) -> Result<Gns, NmeaError> {
    let (t, it) = fs.next();
    let time = opt(t, it, "time", parse_time)?;
    let pos = latlon(fs)?;
    let (m, im) = fs.next();
    if !m.iter().all(u8::is_ascii_uppercase) {
        return Err(NmeaError::BadField {
            index: im,
            what: "mode",
        });
    }
    // One character per constellation; the best of them describes the combined fix.
    let rank = |q: u8| match q {
        quality::RTK_FIXED => 6,
        quality::RTK_FLOAT => 5,
        quality::PPS => 4,
        quality::DGPS => 3,
        quality::GPS => 2,
        quality::ESTIMATED | quality::MANUAL | quality::SIMULATION => 1,
        _ => 0,
    };
    let quality = m
        .iter()
        .map(|&c| quality::from_mode(c))
        .max_by_key(|&q| rank(q))
        .unwrap_or(quality::INVALID);
    let (s, is) = fs.next();
    let sats = opt(s, is, "satellites", parse_u8)?;
    let (h, ih) = fs.next();
    let hdop = opt(h, ih, "hdop", parse_decimal)?;
    let (a, ia) = fs.next();
    let alt_msl = opt(a, ia, "altitude", parse_decimal)?;
    Ok(Gns {
        time,
        pos,
        quality,
        sats,
        hdop,
        alt_msl,
    })
}

fn parse_gll(fs: &mut Fields<'_>) -> Result<Gll, NmeaError> {
    let pos = latlon(fs)?;
    let (t, it) = fs.next();
    let time = opt(t, it, "time", parse_time)?;
    let (s, is) = fs.next();
    let valid = status(s, is)?;
    let (m, im) = fs.next();
    let mode = mode_char(m, im)?;
    Ok(Gll {
        pos,
        time,
        valid,
        mode,
    })
}

fn parse_zda(fs: &mut Fields<'_>) -> Result<Zda, NmeaError> {
    let (t, it) = fs.next();
    let time = opt(t, it, "time", parse_time)?;
    let (d, id) = fs.next();
    let (m, _) = fs.next();
    let (y, iy) = fs.next();
    let day = opt(d, id, "day", parse_u8)?;
    let month = opt(m, id + 1, "month", parse_u8)?;
    let year = opt(y, iy, "year", |f| {
        (f.len() == 4)
            .then(|| parse_decimal(f))
            .flatten()
            .map(|v| v as u16)
    })?;
    let date = match (year, month, day) {
        (Some(y), Some(m), Some(d)) => Some(Date::new(y, m, d).ok_or(NmeaError::BadField {
            index: id,
            what: "date",
        })?),
        _ => None,
    };
    Ok(Zda { time, date })
}

/// Parse one line (`$` … optional `*hh`, without CR/LF). Never panics, never allocates.
pub fn parse(line: &[u8]) -> Result<Sentence, NmeaError> {
    let body = match line.first() {
        Some(b'$') | Some(b'!') => &line[1..],
        _ => return Err(NmeaError::NoStart),
    };
    let (data, checksum_state) = match body.iter().rposition(|&b| b == b'*') {
        Some(star) => {
            let (data, tail) = (&body[..star], &body[star + 1..]);
            let given = match tail {
                [h, l] => match (hex_digit(*h), hex_digit(*l)) {
                    (Some(h), Some(l)) => h << 4 | l,
                    _ => return Err(NmeaError::BadChecksumSyntax),
                },
                _ => return Err(NmeaError::BadChecksumSyntax),
            };
            let computed = checksum(data);
            if given != computed {
                return Err(NmeaError::ChecksumMismatch { given, computed });
            }
            (data, Checksum::Valid)
        }
        None => (body, Checksum::Absent),
    };
    let addr_end = data.iter().position(|&b| b == b',').unwrap_or(data.len());
    let addr = &data[..addr_end];
    let proprietary = addr.first() == Some(&b'P');
    if addr.len() < 2
        || (addr.len() > ADDRESS_MAX && !proprietary)
        || !addr.iter().all(u8::is_ascii_alphanumeric)
    {
        return Err(NmeaError::BadAddress);
    }
    if addr_end == data.len() {
        return Err(NmeaError::NoFields);
    }
    let kept = addr.len().min(ADDRESS_MAX);
    let mut address = [0u8; ADDRESS_MAX];
    address[..kept].copy_from_slice(&addr[..kept]);
    let mut fs = Fields {
        rest: data.get(addr_end + 1..),
        index: 0,
    };
    // Proprietary sentences (`P…`) are never one of ours even if they end in GGA.
    let kind: &[u8] = if proprietary || addr.len() != 5 {
        b""
    } else {
        &addr[2..]
    };
    let body = match kind {
        b"GGA" => Body::Gga(parse_gga(&mut fs)?),
        b"RMC" => Body::Rmc(parse_rmc(&mut fs)?),
        b"GNS" => Body::Gns(parse_gns(&mut fs)?),
        b"GLL" => Body::Gll(parse_gll(&mut fs)?),
        b"ZDA" => Body::Zda(parse_zda(&mut fs)?),
        _ => Body::Other,
    };
    Ok(Sentence {
        address,
        address_len: kept as u8,
        checksum: checksum_state,
        body,
    })
}

/// Append `$<data>*hh` to `out`: the checksum is computed here. `data` excludes `$` and `*`.
pub(crate) fn finish_sentence(out: &mut String, data: &str) {
    use fmt::Write;
    out.push('$');
    out.push_str(data);
    let _ = write!(out, "*{:02X}", checksum(data.as_bytes()));
}

/// Format degrees as NMEA `(d)ddmm.mmmmmmm,H`, with `decimals` fraction digits of minutes.
pub(crate) fn format_coord(out: &mut String, deg: f64, is_lat: bool, decimals: usize) {
    use fmt::Write;
    let hemi = match (is_lat, deg < 0.0) {
        (true, false) => 'N',
        (true, true) => 'S',
        (false, false) => 'E',
        (false, true) => 'W',
    };
    // Round once in integer units of the last minute digit so 59.99999 never prints as 60.
    let scale = 10f64.powi(decimals as i32);
    let units = (deg.abs() * 60.0 * scale).round() as u64;
    let per_deg = 60 * scale as u64;
    let d = units / per_deg;
    let rem = units % per_deg;
    let (m_int, m_frac) = (rem / scale as u64, rem % scale as u64);
    let width = if is_lat { 2 } else { 3 };
    let _ = if decimals > 0 {
        write!(out, "{d:0width$}{m_int:02}.{m_frac:0decimals$},{hemi}")
    } else {
        write!(out, "{d:0width$}{m_int:02},{hemi}")
    };
}

/// Minute decimals written by [`write_gga`]/[`write_rmc`]: 1e-7′ ≈ 0.2 mm, below any receiver.
pub const WRITE_MINUTE_DECIMALS: usize = 7;

fn push_time(out: &mut String, t: &UtcTime) {
    use fmt::Write;
    let _ = write!(
        out,
        "{:02}{:02}{:02}.{:03}",
        t.hour, t.minute, t.second, t.millis
    );
}

/// Append a complete GGA sentence (`$…*hh`, no line terminator): the inverse of [`parse`] for
/// simulated receivers and round-trip tests. `alt_msl`/`geoid_sep` in metres.
#[allow(clippy::too_many_arguments)] // mirrors the sentence's fields one to one
pub fn write_gga(
    out: &mut String,
    time: &UtcTime,
    pos: LatLon,
    quality: u8,
    sats: u8,
    hdop: f64,
    alt_msl: f64,
    geoid_sep: f64,
) {
    use fmt::Write;
    let mut d = String::with_capacity(96);
    d.push_str("GPGGA,");
    push_time(&mut d, time);
    d.push(',');
    format_coord(&mut d, pos.lat, true, WRITE_MINUTE_DECIMALS);
    d.push(',');
    format_coord(&mut d, pos.lon, false, WRITE_MINUTE_DECIMALS);
    let _ = write!(
        d,
        ",{quality},{sats:02},{hdop:.2},{alt_msl:.3},M,{geoid_sep:.3},M,,"
    );
    finish_sentence(out, &d);
}

/// Append a complete RMC sentence (status `A` unless `mode` is `N`; speed and course 0).
pub fn write_rmc(out: &mut String, time: &UtcTime, date: &Date, pos: LatLon, mode: u8) {
    use fmt::Write;
    let mut d = String::with_capacity(96);
    d.push_str("GPRMC,");
    push_time(&mut d, time);
    d.push_str(if mode == b'N' { ",V," } else { ",A," });
    format_coord(&mut d, pos.lat, true, WRITE_MINUTE_DECIMALS);
    d.push(',');
    format_coord(&mut d, pos.lon, false, WRITE_MINUTE_DECIMALS);
    let _ = write!(
        d,
        ",0.000,0.0,{:02}{:02}{:02},,,{}",
        date.day,
        date.month,
        date.year % 100,
        mode as char
    );
    finish_sentence(out, &d);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gga_fields_and_checksum() {
        let s = parse(b"$GNGGA,003956.00,4552.65403,S,17030.00668,E,1,12,0.64,14.2,M,1.8,M,,*56")
            .unwrap();
        assert_eq!(s.address(), "GNGGA");
        assert_eq!(s.talker(), "GN");
        let Body::Gga(g) = s.body else {
            panic!("{s:?}")
        };
        assert_eq!(g.quality, 1);
        assert_eq!(g.sats, Some(12));
        assert_eq!(g.hdop, Some(0.64));
        assert_eq!(g.alt_msl, Some(14.2));
        let p = g.pos.unwrap();
        assert!((p.lat - -(45.0 + 52.65403 / 60.0)).abs() < 1e-12);
        assert!((p.lon - (170.0 + 30.00668 / 60.0)).abs() < 1e-12);
        assert_eq!(g.time.unwrap().ms_of_day(), 39 * 60_000 + 56_000);
    }

    #[test]
    fn checksum_present_absent_and_wrong() {
        let s = parse(b"$GPZDA,201530.00,04,07,2002,00,00*60").unwrap();
        assert_eq!(s.checksum, Checksum::Valid);
        let none = parse(b"$GPZDA,201530.00,04,07,2002,00,00").unwrap();
        assert_eq!(none.checksum, Checksum::Absent);
        assert_eq!(none.body, s.body);
        assert!(matches!(
            parse(b"$GPZDA,201530.00,04,07,2002,00,00*61"),
            Err(NmeaError::ChecksumMismatch {
                given: 0x61,
                computed: 0x60
            })
        ));
        assert_eq!(
            parse(b"$GPZDA,201530.00*6"),
            Err(NmeaError::BadChecksumSyntax)
        );
        assert_eq!(
            parse(b"$GPZDA,201530.00*6G"),
            Err(NmeaError::BadChecksumSyntax)
        );
    }

    #[test]
    fn lower_case_hex_digits_accepted() {
        // Real Trimble sentence (nmea-rtk.log) whose checksum 6A has a hex letter.
        let upper = "$GNGGA,132819.60,4134.49795459,N,09345.03431408,W,2,10,0.9,278.161,M,-31.442,M,6.6,0133*6A";
        let lower = upper.replace("*6A", "*6a");
        assert_eq!(
            parse(lower.as_bytes()).unwrap(),
            parse(upper.as_bytes()).unwrap()
        );
        assert!(parse(upper.replace("*6A", "*6B").as_bytes()).is_err());
    }

    #[test]
    fn no_fix_states_yield_no_position() {
        let lines: [&[u8]; 4] = [
            b"$GPGGA,102136.000,3340.8472,S,15117.3205,E,0,02,99.0,064.19,M,22.4,M,,*41",
            b"$GPRMC,102136.000,V,3340.8472,S,15117.3205,E,0.0,0.0,251112,0.0,W*79",
            b"$GPGLL,3340.8472,S,15117.3205,E,102136.000,V,N",
            b"$GNGNS,102136.00,3340.8472,S,15117.3205,E,NN,02,99.0,64.19,22.4,,",
        ];
        for l in lines {
            let s = parse(l).unwrap_or_else(|e| panic!("{}: {e}", String::from_utf8_lossy(l)));
            assert_eq!(s.position(), None, "{}", String::from_utf8_lossy(l));
            assert!(s.time().is_some());
        }
    }

    #[test]
    fn empty_fields_are_none() {
        let s = parse(b"$GPGGA,,,,,,0,,,,,,,,").unwrap();
        let Body::Gga(g) = s.body else { panic!() };
        assert_eq!(
            (g.time, g.pos, g.sats, g.hdop, g.alt_msl),
            (None, None, None, None, None)
        );
        let s = parse(b"$GPRMC,,V,,,,,,,,,,N").unwrap();
        assert!(matches!(
            s.body,
            Body::Rmc(Rmc {
                valid: false,
                pos: None,
                date: None,
                ..
            })
        ));
        // Truncated sentences read missing trailing fields as empty.
        let s = parse(b"$GPGGA,120000").unwrap();
        assert!(matches!(
            s.body,
            Body::Gga(Gga {
                pos: None,
                quality: 0,
                ..
            })
        ));
    }

    #[test]
    fn leap_second_60_is_accepted() {
        let s = parse(b"$GPRMC,235960.50,A,4552.65403,S,17030.00668,E,0.0,,311216,,,A").unwrap();
        let t = s.time().unwrap();
        assert_eq!((t.second, t.millis), (60, 500));
        assert_eq!(t.ms_of_day(), 86_400_500);
        assert_eq!(t.to_string(), "23:59:60.500");
        assert!(parse(b"$GPRMC,235961,A,4552.65403,S,17030.00668,E,0.0,,311216,,,A").is_err());
    }

    #[test]
    fn gns_mode_and_other_talkers() {
        let s = parse(b"$GNGNS,112257.00,3844.24011,N,00908.43828,W,AN,12,0.84,145.2,50.2,,,V")
            .unwrap();
        let (p, q) = s.position().unwrap();
        assert_eq!(q, quality::GPS);
        assert!((p.lon + (9.0 + 8.43828 / 60.0)).abs() < 1e-12);
        let Body::Gns(g) = s.body else { panic!() };
        assert_eq!(
            (g.sats, g.hdop, g.alt_msl),
            (Some(12), Some(0.84), Some(145.2))
        );
        for talker in ["GP", "GN", "GL", "GA", "GB", "BD", "GQ", "QZ", "GI"] {
            let line =
                format!("{talker}GGA,120000.00,4552.65403,S,17030.00668,E,4,12,0.6,14.2,M,1.8,M,,");
            let mut out = String::new();
            finish_sentence(&mut out, &line);
            let s = parse(out.as_bytes()).unwrap();
            assert_eq!(s.talker(), talker);
            assert_eq!(s.position().unwrap().1, quality::RTK_FIXED);
        }
        let p = parse(b"$PGRME,15.0,M,45.0,M,25.0,M*1C").unwrap();
        assert_eq!((p.talker(), p.body), ("P", Body::Other));
    }

    #[test]
    fn malformed_fields_are_errors_naming_the_field() {
        let e = parse(b"$GPGGA,120000,45x2.6,S,17030.00668,E,1,12,0.6,14.2,M,1.8,M,,").unwrap_err();
        assert_eq!(
            e,
            NmeaError::BadField {
                index: 2,
                what: "latitude"
            }
        );
        assert!(parse(b"$GPGGA,126000,4552.6,S,17030.00668,E,1,12,0.6,14.2,M,1.8,M,,").is_err());
        assert!(parse(b"$GPGGA,120000,4560.0,S,17030.00668,E,1,12,0.6,14.2,M,1.8,M,,").is_err());
        assert!(parse(b"$GPGGA,120000,4552.6,X,17030.00668,E,1,12,0.6,14.2,M,1.8,M,,").is_err());
        // An RMC's corrupt date is dropped, not the sentence (see `corrupt_rmc_date_is_dropped`).
        assert!(parse(b"$GPRMC,120000,A,4552.6,X,17030.00668,E,,,120119,,,A").is_err());
        assert_eq!(parse(b"GPGGA,1"), Err(NmeaError::NoStart));
        assert_eq!(parse(b"$G"), Err(NmeaError::BadAddress));
        assert_eq!(parse(b"$"), Err(NmeaError::BadAddress));
        assert_eq!(parse(b"$PQVERNO"), Err(NmeaError::NoFields));
    }

    #[test]
    fn corrupt_rmc_date_is_dropped() {
        // From a real receiver; gpsd reports lat 48.483341667, lon 0.366691667 and no time.
        let s = parse(b"$GPRMC,000231.099,A,4829.0005,N,00022.0015,E,0.15,212.28,2208-1,,,A*73")
            .unwrap();
        let Body::Rmc(r) = s.body else { panic!() };
        assert_eq!((r.date, r.date_dropped), (None, true));
        let (p, q) = s.position().unwrap();
        assert!((p.lat - 48.483341667).abs() < 1e-9 && (p.lon - 0.366691667).abs() < 1e-9);
        assert_eq!(q, quality::GPS);
        for bad in ["320119", "120019", "12011", "1201190", "12-119"] {
            let line = format!("$GPRMC,120000,A,4552.6,S,17030.00668,E,,,{bad},,,A");
            let Body::Rmc(r) = parse(line.as_bytes()).unwrap().body else {
                panic!()
            };
            assert_eq!((r.date, r.date_dropped), (None, true), "{bad}");
        }
        // An empty date is not a dropped one.
        let Body::Rmc(r) = parse(b"$GPRMC,120000,A,4552.6,S,17030.00668,E,,,,,,A")
            .unwrap()
            .body
        else {
            panic!()
        };
        assert_eq!((r.date, r.date_dropped), (None, false));
    }

    #[test]
    fn zda_and_date_helpers() {
        // MT3339 (mt3339.log): empty local-zone fields.
        let s = parse(b"$GPZDA,202640.000,13,04,2015,,*54").unwrap();
        let Body::Zda(z) = s.body else { panic!() };
        assert_eq!(z.date, Date::new(2015, 4, 13));
        assert_eq!(z.time.unwrap().to_string(), "20:26:40.000");
        let d = Date::new(2016, 12, 31).unwrap();
        assert_eq!(d.succ(), Date::new(2017, 1, 1).unwrap());
        assert_eq!(d.succ().pred(), d);
        assert_eq!(
            Date::new(2024, 2, 28).unwrap().succ(),
            Date::new(2024, 2, 29).unwrap()
        );
        assert_eq!(Date::new(1970, 1, 1).unwrap().days_since_epoch(), 0);
        assert_eq!(Date::new(2000, 3, 1).unwrap().days_since_epoch(), 11_017);
        assert!(Date::new(2023, 2, 29).is_none());
    }

    #[test]
    fn decimal_parser_matches_core() {
        for s in [
            "0.64",
            "064.19",
            "-31.442",
            "1127.7",
            "0",
            "12345678901234567890.5",
            ".5",
            "5.",
        ] {
            assert_eq!(parse_decimal(s.as_bytes()), s.parse::<f64>().ok(), "{s}");
        }
        for s in ["", "-", ".", "1.2.3", "1e5", "nan", "--1"] {
            assert_eq!(parse_decimal(s.as_bytes()), None, "{s}");
        }
    }

    #[test]
    fn written_sentences_parse_back() {
        let time = UtcTime {
            hour: 23,
            minute: 59,
            second: 60,
            millis: 250,
            has_fraction: true,
        };
        let date = Date::new(2016, 12, 31).unwrap();
        let pos = LatLon {
            lat: -45.877567166,
            lon: 170.500111333,
        };
        let mut s = String::new();
        write_gga(&mut s, &time, pos, quality::RTK_FIXED, 12, 0.64, 14.2, 1.8);
        let Body::Gga(g) = parse(s.as_bytes()).unwrap().body else {
            panic!("{s}")
        };
        let p = g.pos.unwrap();
        assert!(
            (p.lat - pos.lat).abs() < 1e-9 && (p.lon - pos.lon).abs() < 1e-9,
            "{s}"
        );
        assert_eq!(
            (g.time, g.quality, g.sats, g.hdop, g.alt_msl),
            (Some(time), 4, Some(12), Some(0.64), Some(14.2))
        );
        s.clear();
        write_rmc(&mut s, &time, &date, pos, b'D');
        let p = parse(s.as_bytes()).unwrap();
        assert!(
            matches!(p.body, Body::Rmc(Rmc { date: Some(d), .. }) if d == date),
            "{s}"
        );
        assert_eq!(p.position().unwrap().1, quality::DGPS);
    }

    #[test]
    fn coordinate_formatting_round_trips() {
        let mut out = String::new();
        format_coord(&mut out, -45.877567167, true, 5);
        assert_eq!(out, "4552.65403,S");
        out.clear();
        format_coord(&mut out, 179.99999999999, false, 4);
        assert_eq!(out, "18000.0000,E");
    }
}
