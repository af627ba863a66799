//! Memory check of the serial framing: 100 MB (default) of seeded random bytes, interleaved with
//! real sentences, through framing + parsing + merging in 4 KiB reads, printing the process's peak
//! RSS (`VmHWM`) before and after. Flat memory = the same peak.
//! `cargo run --release --example framing_rss -- [MEGABYTES]`

use infraloc::gnss::Decoder;
use rand::{RngCore, SeedableRng};
use rand_chacha::ChaCha8Rng;

const READ_SIZE: usize = 4096;
const SEED: u64 = 20261121;
/// A valid sentence spliced in every this many reads, so the parser and merger work too.
const SENTENCE_EVERY: usize = 16;

fn vm_hwm_kib() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse().ok())
        })
        .unwrap_or(0)
}

fn main() {
    let mb: usize = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(100);
    let total = mb * 1_000_000;
    let mut rng = ChaCha8Rng::seed_from_u64(SEED);
    let mut buf = vec![0u8; READ_SIZE];
    let sentence =
        b"\r\n$GNGGA,003956.00,4552.65403,S,17030.00668,E,1,12,0.64,14.2,M,1.8,M,,*56\r\n";
    let mut d = Decoder::new();
    let mut fixes = 0u64;
    let before = vm_hwm_kib();
    let t = std::time::Instant::now();
    let mut fed = 0usize;
    let mut reads = 0usize;
    while fed < total {
        rng.fill_bytes(&mut buf);
        d.push(&buf, |_| fixes += 1);
        if reads % SENTENCE_EVERY == 0 {
            d.push(sentence, |_| fixes += 1);
        }
        fed += buf.len();
        reads += 1;
    }
    let after = vm_hwm_kib();
    let s = d.stats();
    let f = d.framing_stats();
    println!(
        "{} MB random bytes in {:.2} s: {} lines, {} sentences, {} fixes, {} over-long, {} binary lines",
        fed / 1_000_000,
        t.elapsed().as_secs_f64(),
        s.lines,
        s.sentences,
        fixes,
        f.overlong_lines,
        f.binary_lines
    );
    println!(
        "peak RSS (VmHWM): before {before} KiB, after {after} KiB, growth {} KiB",
        after.saturating_sub(before)
    );
}
