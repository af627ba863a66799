//! Prior acquisition from the configured sources (`gps_serial::acquire_prior`) on real logs.

use crate::common;

use infraloc::config::{GpsConfig, GpsSourceKind};
use infraloc::gnss::PriorOutcome;
use infraloc::gps_serial::{acquire_prior, decode_file};

fn file_config(path: std::path::PathBuf) -> GpsConfig {
    GpsConfig {
        source: GpsSourceKind::NmeaFile,
        path: Some(path),
        fallback_wgs84: Some([44.0, -121.0]),
        ..GpsConfig::default()
    }
}

#[test]
fn nmea_file_prior_averages_the_last_window() {
    // MT3339 (Bend, Oregon): 30 s of DGPS fixes, HDOP ≈ 0.9.
    let log = common::nmea_dir().join("mt3339.log");
    let (fixes, _) = decode_file(&log).unwrap();
    let PriorOutcome::Gnss(e) = acquire_prior(&file_config(log)).unwrap() else {
        panic!("no GNSS prior")
    };
    // One fix per epoch: the log has 30 epochs (GGA+RMC each), all inside a 30 s window.
    let epochs: std::collections::BTreeSet<u32> =
        fixes.iter().map(|f| f.time.unwrap().ms_of_day()).collect();
    assert_eq!(e.used + e.rejected, epochs.len().min(31));
    // The estimate lies inside the cloud of fixes (a few decimetres across) and σ is DGPS-sized.
    let (lat_min, lat_max) = fixes
        .iter()
        .fold((90f64, -90f64), |(a, b), f| (a.min(f.lat), b.max(f.lat)));
    let (lon_min, lon_max) = fixes
        .iter()
        .fold((180f64, -180f64), |(a, b), f| (a.min(f.lon), b.max(f.lon)));
    assert!(
        (lat_min..=lat_max).contains(&e.lat) && (lon_min..=lon_max).contains(&e.lon),
        "{e:?}"
    );
    assert!(
        e.sigma_m > 0.5 && e.sigma_m < 2.0,
        "DGPS: HDOP·1 m ⊕ scatter: {e:?}"
    );
    assert!((e.alt_msl.unwrap() - 1127.7).abs() < 1.0);
}

#[test]
fn no_fix_log_falls_back_with_a_reason() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("cold.nmea");
    // sl869's cold start: sentences, no fix.
    std::fs::write(
        &p,
        "$GPRMC,102136.000,V,3340.8472,S,15117.3205,E,0.0,0.0,251112,0.0,W*79\r\n\
         $GPGGA,102136.000,3340.8472,S,15117.3205,E,0,02,99.0,064.19,M,22.4,M,,*41\r\n",
    )
    .unwrap();
    match acquire_prior(&file_config(p.clone())).unwrap() {
        PriorOutcome::Fallback {
            lat, lon, reason, ..
        } => {
            assert_eq!((lat, lon), (44.0, -121.0));
            assert!(
                reason.contains("cold.nmea") && reason.contains("0 fixes"),
                "{reason}"
            );
        }
        o => panic!("{o:?}"),
    }
    let fixed = GpsConfig {
        source: GpsSourceKind::Fixed,
        ..file_config(p)
    };
    assert!(
        matches!(acquire_prior(&fixed).unwrap(), PriorOutcome::Fixed { lat, .. } if lat == 44.0)
    );
    let missing = file_config(dir.path().join("absent.nmea"));
    let e = acquire_prior(&missing).unwrap_err().to_string();
    assert!(e.contains("absent.nmea") && !e.contains('\n'), "{e}");
}
