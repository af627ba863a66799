//! `infraloc gps …`: GNSS tools.

use crate::error::{Error, Result};
use crate::gnss::Decoder;
use std::io::{BufWriter, Read, Write};
use std::path::PathBuf;

/// Read the log in chunks of this size (streaming: logs may be large, memory stays flat).
const CHUNK: usize = 64 * 1024;

/// GPS subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum Command {
    /// NMEA log → one JSON line per fix (time, lat, lon, alt_msl, quality, sats, hdop,
    /// source_sentence) on stdout; a one-line summary on stderr.
    Decode(DecodeArgs),
}

/// Arguments of `gps decode`.
#[derive(Debug, clap::Args)]
pub struct DecodeArgs {
    /// NMEA 0183 log (any line endings; garbage and non-NMEA lines are skipped and counted).
    pub file: PathBuf,
}

/// Run a gps subcommand.
pub(super) fn run(c: Command) -> Result<()> {
    match c {
        Command::Decode(a) => decode(&a.file),
    }
}

fn decode(path: &std::path::Path) -> Result<()> {
    let mut file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let stdout = std::io::stdout();
    let mut out = BufWriter::new(stdout.lock());
    let mut d = Decoder::for_log_files();
    let mut buf = vec![0u8; CHUNK];
    let mut write_err: Option<std::io::Error> = None;
    let mut emit = |f: crate::gnss::Fix| {
        if write_err.is_some() {
            return;
        }
        // Serialise first, so a closed stdout is the write's own BrokenPipe, not a serde error.
        let r = serde_json::to_string(&f.record())
            .map_err(std::io::Error::other)
            .and_then(|line| {
                out.write_all(line.as_bytes())?;
                out.write_all(b"\n")
            });
        if let Err(e) = r {
            write_err = Some(e);
        }
    };
    loop {
        let n = file.read(&mut buf).map_err(|e| Error::io(path, e))?;
        if n == 0 {
            break;
        }
        d.push(&buf[..n], &mut emit);
    }
    d.finish(&mut emit);
    let flushed = match write_err {
        Some(e) => Err(e),
        None => out.flush(),
    };
    match flushed {
        // The reader has all it wanted (`gps decode log | head`): stop quietly, as Unix tools do.
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => return Ok(()),
        Err(e) => return Err(Error::io("<stdout>", e)),
        Ok(()) => {}
    }
    let s = d.stats();
    let fr = d.framing_stats();
    eprintln!(
        "{}: {} fixes from {} sentences ({} without fix, {} corrupt dates dropped, {} checksum errors, {} unparsable, {} garbage bytes, {} over-long lines)",
        path.display(),
        s.fixes,
        s.sentences,
        s.no_fix_sentences,
        s.dropped_dates,
        s.checksum_errors,
        s.parse_errors,
        fr.garbage_bytes,
        fr.overlong_lines
    );
    if s.sentences == 0 {
        return Err(Error::input(path, "no NMEA sentence found"));
    }
    Ok(())
}
