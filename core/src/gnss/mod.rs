//! GNSS: NMEA 0183 framing and parsing, per-epoch merging into fixes, and the position prior.
//! Pure: no files, sockets or clocks here; the serial reader lives in the shell
//! (the application's `gps_serial`). See `docs/gnss.md`.

pub(crate) mod epoch;
pub mod framing;
pub mod nmea;
pub mod prior;

pub use epoch::{EpochMerger, Fix};

pub use framing::LineFramer;
pub use prior::PriorOutcome;
pub use prior::{PriorEstimator, PriorSettings};

/// Counters of a decoding pipeline (framing + parsing + merging), for statuses and summaries.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct DecodeStats {
    /// Lines framed.
    pub lines: u64,
    /// Lines that parsed as sentences.
    pub sentences: u64,
    /// Sentences accepted without a checksum (see `docs/gnss.md`).
    pub unchecked_sentences: u64,
    /// Lines with a wrong checksum.
    pub checksum_errors: u64,
    /// Other unparsable lines (bad address, malformed field of a known sentence).
    pub parse_errors: u64,
    /// Fixes produced.
    pub fixes: u64,
    /// Sentences that declared no fix.
    pub no_fix_sentences: u64,
    /// RMC sentences kept without their corrupt date field (position kept, as gpsd does).
    pub dropped_dates: u64,
}

impl DecodeStats {
    /// The counts in words, for a technician: `120 lines: 80 sentences (37 lines with checksum
    /// errors, 3 unparsable, 20 sentences without a fix, 1 corrupt date dropped), 60 fixes`.
    pub fn describe(&self) -> String {
        let plural =
            |n: u64, one: &str, many: &str| format!("{n} {}", if n == 1 { one } else { many });
        let mut notes = Vec::new();
        if self.checksum_errors > 0 {
            notes.push(format!(
                "{} with checksum errors",
                plural(self.checksum_errors, "line", "lines")
            ));
        }
        if self.parse_errors > 0 {
            notes.push(format!("{} unparsable", self.parse_errors));
        }
        if self.no_fix_sentences > 0 {
            notes.push(format!(
                "{} without a fix",
                plural(self.no_fix_sentences, "sentence", "sentences")
            ));
        }
        if self.dropped_dates > 0 {
            notes.push(format!(
                "{} dropped",
                plural(self.dropped_dates, "corrupt date", "corrupt dates")
            ));
        }
        let notes = if notes.is_empty() {
            String::new()
        } else {
            format!(" ({})", notes.join(", "))
        };
        format!(
            "{}: {}{notes}, {}",
            plural(self.lines, "line", "lines"),
            plural(self.sentences, "sentence", "sentences"),
            plural(self.fixes, "fix", "fixes")
        )
    }
}

/// Framing + parsing + merging in one: bytes in, fixes out. Used by the file decoder, the serial
/// reader and the fuzz target alike, so they cannot disagree.
#[derive(Debug, Clone, Default)]
pub struct Decoder {
    framer: LineFramer,
    merger: EpochMerger,
    stats: DecodeStats,
}

impl Decoder {
    /// A fresh decoder.
    pub fn new() -> Self {
        Self::default()
    }

    /// A decoder for log files: `#` comment lines are skipped (see [`LineFramer::for_log_files`]).
    pub fn for_log_files() -> Self {
        Decoder {
            framer: LineFramer::for_log_files(),
            ..Self::default()
        }
    }

    /// Counters so far.
    pub fn stats(&self) -> DecodeStats {
        let m = self.merger.stats();
        DecodeStats {
            fixes: m.fixes,
            no_fix_sentences: m.no_fix_sentences,
            ..self.stats
        }
    }

    /// Framing counters (garbage, over-long lines…).
    pub fn framing_stats(&self) -> framing::FramingStats {
        self.framer.stats()
    }

    fn line(
        merger: &mut EpochMerger,
        stats: &mut DecodeStats,
        line: &[u8],
        on_fix: &mut impl FnMut(Fix),
    ) {
        stats.lines += 1;
        match nmea::parse(line) {
            Ok(s) => {
                stats.sentences += 1;
                if s.checksum == nmea::Checksum::Absent {
                    stats.unchecked_sentences += 1;
                }
                if matches!(s.body, nmea::Body::Rmc(r) if r.date_dropped) {
                    stats.dropped_dates += 1;
                }
                if let Some(f) = merger.push(&s) {
                    on_fix(f);
                }
            }
            Err(nmea::NmeaError::ChecksumMismatch { .. }) => stats.checksum_errors += 1,
            Err(_) => stats.parse_errors += 1,
        }
    }

    /// Feed bytes (any chunking); `on_fix` gets every fix they complete.
    pub fn push(&mut self, bytes: &[u8], mut on_fix: impl FnMut(Fix)) {
        let (merger, stats) = (&mut self.merger, &mut self.stats);
        self.framer
            .push(bytes, |l| Self::line(merger, stats, l, &mut on_fix));
    }

    /// End of input: a last line without terminator is decoded too.
    pub fn finish(&mut self, mut on_fix: impl FnMut(Fix)) {
        let (merger, stats) = (&mut self.merger, &mut self.stats);
        self.framer
            .finish(|l| Self::line(merger, stats, l, &mut on_fix));
    }

    /// Drop a partial line (after a reconnect). Epoch state is kept: merging is keyed on time.
    pub fn reset_line(&mut self) {
        self.framer.reset();
    }
}
