//! Every real receiver log of `shared/data/nmea/` decoded and compared with gpsd's own decode
//! (`.log.chk`: each accepted input sentence echoed, then gpsd's JSON reports).
//!
//! Checked per log:
//! - the sentences we accept are exactly the ones gpsd echoes (same order), so we reject what
//!   gpsd rejects (e.g. garmin48's truncated `*7` checksum) and nothing else;
//! - every GGA/RMC fix followed by a TPV: lat/lon ≤ 1e-8°, altMSL ≤ 1e-3 m (GGA), time to the
//!   millisecond when gpsd reports one (gpsd withholds time until it has a date; then we must
//!   have the same date too);
//! - every GGA/RMC we call "no fix" is followed by a TPV with mode ≤ 1, and every fix by mode ≥ 2.

use crate::common;

use common::{nmea_dir, nmea_logs, Reference};
use infraloc::gnss::framing::LineFramer;
use infraloc::gnss::nmea::{self, Body};
use infraloc::gnss::{Decoder, EpochMerger};
use std::path::Path;

const LATLON_TOL_DEG: f64 = 1e-8;
const ALT_TOL_M: f64 = 1e-3;

/// What one log's comparison covered.
#[derive(Default)]
struct Counts {
    compared: usize,
    times_compared: usize,
    no_fix_checked: usize,
    unchecked: usize,
    dropped_dates: usize,
    max_dll: f64,
    max_dalt: f64,
    max_dt_ms: i64,
}

/// Decode `log` as the service does and compare it with gpsd's `.log.chk` beside it (the checks
/// listed at the top of this file); panics naming the log and sentence on a difference.
fn compare_with_gpsd(log: &Path) -> Counts {
    let mut c = Counts::default();
    let bytes = std::fs::read(log).unwrap();
    let chk = Reference::load(&log.with_extension("log.chk"));
    let mut framer = LineFramer::for_log_files();
    let mut merger = EpochMerger::new();
    let mut accepted: Vec<String> = Vec::new();
    let echoed: Vec<&str> = chk.entries.iter().map(|e| e.sentence.as_str()).collect();
    let mut results = Vec::new();
    let mut lines = Vec::new();
    framer.push(&bytes, |l| lines.push(l.to_vec()));
    framer.finish(|l| lines.push(l.to_vec()));
    for l in &lines {
        if let Ok(s) = nmea::parse(l) {
            let text = String::from_utf8(l.clone()).unwrap();
            // Our one documented difference: a sentence without checksum is accepted (gpsd
            // drops sl869's `$GPTXT,TELIT SW Version…`). It must carry no fix to matter.
            if s.checksum == nmea::Checksum::Absent
                && echoed.get(accepted.len()) != Some(&text.as_str())
            {
                assert!(
                    s.position().is_none(),
                    "{}: unchecked fix {text}",
                    log.display()
                );
                c.unchecked += 1;
                continue;
            }
            accepted.push(String::from_utf8(l.clone()).unwrap());
            let fix = merger.push(&s);
            results.push((s, fix));
        }
    }
    if let Some(i) = (0..accepted.len().max(echoed.len()))
        .find(|&i| accepted.get(i).map(String::as_str) != echoed.get(i).copied())
    {
        panic!(
            "{}: sentence {i} differs: ours {:?}, gpsd {:?}",
            log.display(),
            accepted.get(i),
            echoed.get(i)
        );
    }
    let name = log.file_name().unwrap().to_string_lossy().to_string();
    let mut n_log = 0;
    for ((s, fix), entry) in results.iter().zip(&chk.entries) {
        let is_gga = matches!(s.body, Body::Gga(_));
        let dropped_date = matches!(s.body, Body::Rmc(r) if r.date_dropped);
        if !(is_gga || matches!(s.body, Body::Rmc(_))) {
            continue;
        }
        let Some(tpv) = &entry.tpv else { continue };
        let mode = tpv["mode"].as_i64().unwrap();
        let Some(fix) = fix else {
            assert!(
                mode <= 1,
                "{name}: {} has no fix for us, gpsd mode {mode}",
                entry.sentence
            );
            c.no_fix_checked += 1;
            continue;
        };
        assert!(
            mode >= 2,
            "{name}: {} is a fix for us, gpsd mode {mode}",
            entry.sentence
        );
        let dlat = (fix.lat - tpv["lat"].as_f64().unwrap()).abs();
        let dlon = (fix.lon - tpv["lon"].as_f64().unwrap()).abs();
        assert!(
            dlat <= LATLON_TOL_DEG && dlon <= LATLON_TOL_DEG,
            "{name}: {} Δ {dlat:e} {dlon:e}",
            entry.sentence
        );
        c.max_dll = c.max_dll.max(dlat).max(dlon);
        if is_gga {
            let want = tpv["altMSL"].as_f64().unwrap();
            let dalt = (fix.alt_msl.unwrap() - want).abs();
            assert!(
                dalt <= ALT_TOL_M,
                "{name}: {} altMSL Δ {dalt}",
                entry.sentence
            );
            c.max_dalt = c.max_dalt.max(dalt);
        }
        if dropped_date {
            // gpsd sets no time from an RMC whose date it cannot read: its TPV has none, or
            // still the previous sentence's. We keep the sentence's own time of day (the date
            // comes from the epoch or the last good date, as for a GGA), so only that is checked.
            assert_eq!(fix.time, s.time(), "{name}: {}", entry.sentence);
            c.dropped_dates += 1;
        } else if let Some(t) = tpv["time"].as_str() {
            let want_ms = common::iso_to_unix_ms(t);
            let got = fix
                .unix_time()
                .unwrap_or_else(|| panic!("{name}: {} no date, gpsd has {t}", entry.sentence));
            let dt = ((got * 1000.0).round() as i64 - want_ms).abs();
            assert_eq!(
                dt,
                0,
                "{name}: {} time {:?} vs gpsd {t}",
                entry.sentence,
                fix.iso_time()
            );
            c.max_dt_ms = c.max_dt_ms.max(dt);
            c.times_compared += 1;
        }
        c.compared += 1;
        n_log += 1;
    }
    eprintln!(
        "{name}: {} sentences identical to gpsd's echo, {n_log} fixes compared",
        accepted.len()
    );
    c
}

#[test]
fn every_log_matches_gpsd() {
    let logs = nmea_logs();
    assert!(
        logs.len() >= 10,
        "expected the 10 gpsd logs in {}",
        nmea_dir().display()
    );
    let mut t = Counts::default();
    for log in &logs {
        let c = compare_with_gpsd(log);
        t.compared += c.compared;
        t.times_compared += c.times_compared;
        t.no_fix_checked += c.no_fix_checked;
        t.unchecked += c.unchecked;
        t.max_dll = t.max_dll.max(c.max_dll);
        t.max_dalt = t.max_dalt.max(c.max_dalt);
        t.max_dt_ms = t.max_dt_ms.max(c.max_dt_ms);
    }
    eprintln!(
        "TOTAL: {} GGA/RMC fixes compared ({} with time), {} no-fix sentences, {} checksum-less sentences gpsd drops; \
         max |Δlat|,|Δlon| = {:e}°, max |ΔaltMSL| = {:e} m, max |Δt| = {} ms",
        t.compared, t.times_compared, t.no_fix_checked, t.unchecked, t.max_dll, t.max_dalt, t.max_dt_ms
    );
    assert!(
        t.compared >= 150,
        "only {} fixes had a gpsd TPV to compare",
        t.compared
    );
}

/// A receiver's RMC with a corrupt date field (`2208-1`): gpsd keeps its position and drops the
/// date, and so do we; the decode summary counts it. `tests/data/nmea/rmc-bad-date.log` holds
/// the real sentence and a few around it; its `.chk` is gpsd 3.22's decode (how it was made is in
/// the log's header).
#[test]
fn corrupt_rmc_date_keeps_the_position_like_gpsd() {
    let log = Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/nmea/rmc-bad-date.log"
    ));
    let c = compare_with_gpsd(log);
    assert_eq!((c.compared, c.dropped_dates, c.times_compared), (6, 3, 2));

    // The service's decoder: every sentence kept, the three corrupt dates counted and named.
    let mut d = Decoder::for_log_files();
    let mut fixes = Vec::new();
    d.push(&std::fs::read(log).unwrap(), |f| fixes.push(f));
    d.finish(|f| fixes.push(f));
    let st = d.stats();
    assert_eq!(
        (st.sentences, st.parse_errors, st.fixes, st.dropped_dates),
        (6, 0, 6, 3)
    );
    assert!(
        st.describe().contains("3 corrupt dates dropped"),
        "{}",
        st.describe()
    );
    // The sentence: gpsd's lat/lon, no date, so no timestamp (a time of day only).
    let f = &fixes[0];
    assert!((f.lat - 48.483341667).abs() < 1e-9 && (f.lon - 0.366691667).abs() < 1e-9);
    assert_eq!((f.date, f.unix_time()), (None, None));
    assert_eq!(f.iso_time().as_deref(), Some("00:02:31.099Z"));
    // After a good date, a corrupt one is dated like a GGA would be: from the last good date.
    assert_eq!(
        fixes[4].iso_time().as_deref(),
        Some("2021-08-22T00:02:34.099Z")
    );
}
