//! Arbitrary bytes, in arbitrary chunks, through framing + parsing + epoch merging: must never
//! panic, every framed line must fit the cap, and chunking must not change the result.
#![no_main]

use infraloc::gnss::framing::{LineFramer, MAX_LINE};
use infraloc::gnss::{nmea, Decoder};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    // Whole input at once.
    let mut whole = Decoder::new();
    let mut fixes_whole = Vec::new();
    whole.push(data, |f| fixes_whole.push(f));
    whole.finish(|f| fixes_whole.push(f));

    // The same bytes in chunks whose sizes come from the data itself.
    let mut chunked = Decoder::new();
    let mut fixes_chunked = Vec::new();
    let mut rest = data;
    while !rest.is_empty() {
        let n = (rest[0] as usize % 17 + 1).min(rest.len());
        chunked.push(&rest[..n], |f| fixes_chunked.push(f));
        rest = &rest[n..];
    }
    chunked.finish(|f| fixes_chunked.push(f));
    assert_eq!(fixes_whole.len(), fixes_chunked.len());
    for (a, b) in fixes_whole.iter().zip(&fixes_chunked) {
        assert_eq!(a.lat.to_bits(), b.lat.to_bits());
        assert_eq!(a.lon.to_bits(), b.lon.to_bits());
        assert_eq!(a.time, b.time);
        assert_eq!(a.date, b.date);
    }
    for f in &fixes_whole {
        assert!(f.lat.abs() <= 90.0 && f.lon.abs() <= 180.0, "{f:?}");
        let _ = f.record();
    }

    // Lines are bounded, and parsing any line (also unframed input) never panics.
    let mut framer = LineFramer::new();
    framer.push(data, |l| {
        assert!(l.len() <= MAX_LINE);
        let _ = nmea::parse(l);
    });
    let _ = nmea::parse(data);
});
