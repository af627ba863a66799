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

mod common;

use common::{nmea_dir, nmea_logs, Reference};
use infraloc::gnss::framing::LineFramer;
use infraloc::gnss::nmea::{self, Body};
use infraloc::gnss::EpochMerger;

const LATLON_TOL_DEG: f64 = 1e-8;
const ALT_TOL_M: f64 = 1e-3;

#[test]
fn every_log_matches_gpsd() {
    let logs = nmea_logs();
    assert!(
        logs.len() >= 10,
        "expected the 10 gpsd logs in {}",
        nmea_dir().display()
    );
    let (mut compared, mut max_dll, mut max_dalt, mut max_dt_ms) = (0usize, 0f64, 0f64, 0i64);
    let mut times_compared = 0usize;
    let mut no_fix_checked = 0usize;
    let mut unchecked = 0usize;
    for log in &logs {
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
                    unchecked += 1;
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
                no_fix_checked += 1;
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
            max_dll = max_dll.max(dlat).max(dlon);
            if is_gga {
                let want = tpv["altMSL"].as_f64().unwrap();
                let dalt = (fix.alt_msl.unwrap() - want).abs();
                assert!(
                    dalt <= ALT_TOL_M,
                    "{name}: {} altMSL Δ {dalt}",
                    entry.sentence
                );
                max_dalt = max_dalt.max(dalt);
            }
            if let Some(t) = tpv["time"].as_str() {
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
                max_dt_ms = max_dt_ms.max(dt);
                times_compared += 1;
            }
            compared += 1;
            n_log += 1;
        }
        eprintln!(
            "{name}: {} sentences identical to gpsd's echo, {n_log} fixes compared",
            accepted.len()
        );
    }
    eprintln!(
        "TOTAL: {compared} GGA/RMC fixes compared ({times_compared} with time), {no_fix_checked} no-fix sentences, {unchecked} checksum-less sentences gpsd drops; \
         max |Δlat|,|Δlon| = {max_dll:e}°, max |ΔaltMSL| = {max_dalt:e} m, max |Δt| = {max_dt_ms} ms"
    );
    assert!(
        compared >= 150,
        "only {compared} fixes had a gpsd TPV to compare"
    );
}
