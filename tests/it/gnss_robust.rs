//! Garbage, partial and over-long input through the decoder (framing + parsing + merging), on the
//! real logs: noise between sentences and arbitrary read chunking change nothing; a sentence cut
//! off by the next one is lost alone; random bytes never panic and lines stay bounded.

use crate::common;

use infraloc::gnss::framing::{LineFramer, MAX_LINE};
use infraloc::gnss::{Decoder, Fix};
use rand::{Rng, RngCore, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Serial-mode decoding (no `#` comments: noise may contain `#`) in random read sizes.
fn decode_chunks(bytes: &[u8], rng: &mut ChaCha8Rng) -> Vec<Fix> {
    let mut d = Decoder::new();
    let mut out = Vec::new();
    let mut rest = bytes;
    while !rest.is_empty() {
        let n = rng.random_range(1..=64usize).min(rest.len());
        d.push(&rest[..n], |f| out.push(f));
        rest = &rest[n..];
    }
    d.finish(|f| out.push(f));
    out
}

fn decode_with(mut d: Decoder, bytes: &[u8]) -> Vec<Fix> {
    let mut out = Vec::new();
    d.push(bytes, |f| out.push(f));
    d.finish(|f| out.push(f));
    out
}

fn decode(bytes: &[u8]) -> Vec<Fix> {
    decode_with(Decoder::for_log_files(), bytes)
}

fn first_difference(a: &[Fix], b: &[Fix]) -> Option<usize> {
    (0..a.len().max(b.len())).find(|&i| a.get(i) != b.get(i))
}

/// Lines of a log with their terminators.
fn split_lines(text: &[u8]) -> Vec<&[u8]> {
    text.split_inclusive(|&b| b == b'\n').collect()
}

#[test]
fn noise_between_sentences_and_chunking_change_nothing() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    for log in common::nmea_logs() {
        let text = std::fs::read(&log).unwrap();
        let clean = decode_with(Decoder::new(), &text);
        let mut noisy = Vec::new();
        for line in split_lines(&text) {
            noisy.extend_from_slice(line);
            // Garbage without start characters or terminators: binary, printable, XON/XOFF…
            for _ in 0..rng.random_range(0..40) {
                let b: u8 = rng.random();
                if !matches!(b, b'$' | b'!' | b'\r' | b'\n') {
                    noisy.push(b);
                }
            }
            if rng.random_bool(0.1) {
                // An over-long line (a receiver dumping binary-ish text), terminated.
                noisy.extend_from_slice(b"$GPTXT,");
                noisy.extend(std::iter::repeat_n(b'x', 3 * MAX_LINE));
                noisy.extend_from_slice(b"\r\n");
            }
        }
        let got = decode_chunks(&noisy, &mut rng);
        assert!(!clean.is_empty());
        let d = first_difference(&got, &clean);
        assert!(
            d.is_none(),
            "{}: fix {d:?} differs: {:?} vs {:?}",
            log.display(),
            d.and_then(|i| got.get(i)),
            d.and_then(|i| clean.get(i))
        );
    }
}

#[test]
fn a_cut_off_sentence_is_lost_alone() {
    for log in common::nmea_logs() {
        let text = std::fs::read(&log).unwrap();
        let lines = split_lines(&text);
        let (mut cut, mut removed) = (Vec::new(), Vec::new());
        let mut n_cut = 0;
        for (i, l) in lines.iter().enumerate() {
            if i % 7 == 3 && l.starts_with(b"$") {
                // Partial read then receiver reset: half a sentence, no terminator.
                cut.extend_from_slice(&l[..l.len() / 2]);
                n_cut += 1;
            } else {
                cut.extend_from_slice(l);
                removed.extend_from_slice(l);
            }
        }
        assert!(n_cut > 5);
        let (a, b) = (decode(&cut), decode(&removed));
        assert!(first_difference(&a, &b).is_none(), "{}", log.display());
    }
}

#[test]
fn random_bytes_never_panic_and_lines_stay_bounded() {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let mut buf = vec![0u8; 1 << 16];
    let mut d = Decoder::new();
    let mut framer = LineFramer::new();
    let mut longest = 0;
    for _ in 0..64 {
        rng.fill_bytes(&mut buf);
        d.push(&buf, |f| {
            assert!(f.lat.abs() <= 90.0 && f.lon.abs() <= 180.0)
        });
        framer.push(&buf, |l| longest = longest.max(l.len()));
    }
    assert!(longest <= MAX_LINE);
    let s = framer.stats();
    assert!(
        s.binary_lines > 1000 && s.garbage_bytes > 1_000_000,
        "{s:?}"
    );
}
