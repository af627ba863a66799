//! Serial framing: bytes in (any chunking), complete NMEA lines out. A pure state machine with a
//! fixed buffer, so memory is bounded whatever arrives.
//!
//! Rules:
//! - A line starts at `$` (or `!`, AIS-style encapsulation) and ends at CR or LF; CRLF, LF-only,
//!   CR-only and LFCR all work because empty lines are never emitted.
//! - Bytes outside a line (before its start character) are garbage and dropped.
//! - A start character inside a line restarts the line: `$` is reserved in NMEA, so the partial
//!   line before it was cut off (a receiver reset or a lost terminator).
//! - A byte that is not printable ASCII, or a line longer than [`MAX_LINE`], poisons the line: it
//!   is dropped up to the next terminator or start character.
//! - Log files only ([`LineFramer::for_log_files`]): a line starting with `#` is a comment (gpsd's
//!   regression-log headers quote sentences in comments) and dropped whole. Off for serial
//!   streams, where a stray `#` must not swallow the sentence after it.

/// Longest line kept, bytes (NMEA allows 82 including CRLF; some receivers exceed that a bit).
pub const MAX_LINE: usize = 128;

/// Counters of what the framer dropped (for the receiver status).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FramingStats {
    /// Complete lines emitted.
    pub lines: u64,
    /// Bytes dropped outside any line.
    pub garbage_bytes: u64,
    /// Lines dropped for exceeding [`MAX_LINE`].
    pub overlong_lines: u64,
    /// Lines dropped for containing a non-printable byte.
    pub binary_lines: u64,
    /// Lines cut off by a new start character.
    pub truncated_lines: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    /// Waiting for a start character.
    Idle,
    /// Inside a line.
    InLine,
    /// The current line is being dropped until a terminator or start character.
    Discard,
    /// A `#` comment line (log files), dropped until a terminator.
    Comment,
}

/// The framing state machine.
#[derive(Debug, Clone)]
pub struct LineFramer {
    buf: [u8; MAX_LINE],
    len: usize,
    state: State,
    stats: FramingStats,
    comments: bool,
    /// At the start of a line (only whitespace-free terminators seen since the last line).
    at_line_start: bool,
}

impl Default for LineFramer {
    fn default() -> Self {
        Self::new()
    }
}

impl LineFramer {
    /// An idle framer.
    pub fn new() -> Self {
        LineFramer {
            buf: [0; MAX_LINE],
            len: 0,
            state: State::Idle,
            stats: FramingStats::default(),
            comments: false,
            at_line_start: true,
        }
    }

    /// A framer for log files: also drops `#` comment lines.
    pub fn for_log_files() -> Self {
        LineFramer {
            comments: true,
            ..Self::new()
        }
    }

    /// What has been emitted and dropped so far.
    pub fn stats(&self) -> FramingStats {
        self.stats
    }

    /// Feed bytes; `on_line` is called with every complete line (start character included,
    /// terminator excluded). The slice is only valid during the call.
    pub fn push(&mut self, bytes: &[u8], mut on_line: impl FnMut(&[u8])) {
        for &b in bytes {
            let line_start = std::mem::replace(&mut self.at_line_start, false);
            if self.state == State::Comment && b != b'\r' && b != b'\n' {
                continue;
            }
            match b {
                b'#' if self.comments && line_start && self.state == State::Idle => {
                    self.state = State::Comment;
                }
                b'\r' | b'\n' => {
                    self.at_line_start = true;
                    if self.state == State::InLine {
                        self.stats.lines += 1;
                        on_line(&self.buf[..self.len]);
                    }
                    self.state = State::Idle;
                    self.len = 0;
                }
                b'$' | b'!' => {
                    if self.state == State::InLine {
                        self.stats.truncated_lines += 1;
                    }
                    self.buf[0] = b;
                    self.len = 1;
                    self.state = State::InLine;
                }
                _ => match self.state {
                    State::Idle => self.stats.garbage_bytes += 1,
                    State::Discard | State::Comment => {}
                    State::InLine if !(0x20..0x7f).contains(&b) => {
                        self.stats.binary_lines += 1;
                        self.state = State::Discard;
                    }
                    State::InLine if self.len == MAX_LINE => {
                        self.stats.overlong_lines += 1;
                        self.state = State::Discard;
                    }
                    State::InLine => {
                        self.buf[self.len] = b;
                        self.len += 1;
                    }
                },
            }
        }
    }

    /// End of input (a file without a final newline): emit the pending line, if any.
    pub fn finish(&mut self, mut on_line: impl FnMut(&[u8])) {
        if self.state == State::InLine {
            self.stats.lines += 1;
            on_line(&self.buf[..self.len]);
        }
        self.state = State::Idle;
        self.len = 0;
    }

    /// Forget a partial line (after a reconnect the stream restarts mid-line).
    pub(crate) fn reset(&mut self) {
        self.state = State::Idle;
        self.len = 0;
        self.at_line_start = true;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lines_of(chunks: &[&[u8]]) -> Vec<String> {
        let mut f = LineFramer::new();
        let mut out = Vec::new();
        for c in chunks {
            f.push(c, |l| out.push(String::from_utf8(l.to_vec()).unwrap()));
        }
        f.finish(|l| out.push(String::from_utf8(l.to_vec()).unwrap()));
        out
    }

    #[test]
    fn terminator_variants() {
        let want = vec![
            "$A,1".to_string(),
            "$B,2".into(),
            "$C,3".into(),
            "$D,4".into(),
        ];
        assert_eq!(lines_of(&[b"$A,1\r\n$B,2\n$C,3\r$D,4\n\r"]), want);
        assert_eq!(lines_of(&[b"$A,1\r\n\r\n\n$B,2\r\n$C,3\r\n$D,4"]), want);
    }

    #[test]
    fn partial_reads_byte_by_byte_equal_whole() {
        let data = b"junk$GPGGA,1,2*00\r\n$GPRMC,3\r\nxx$GPZDA\r\n";
        let whole = lines_of(&[data]);
        let bytes: Vec<&[u8]> = data.chunks(1).collect();
        assert_eq!(lines_of(&bytes), whole);
        assert_eq!(whole, vec!["$GPGGA,1,2*00", "$GPRMC,3", "$GPZDA"]);
    }

    #[test]
    fn garbage_binary_and_restart() {
        let mut f = LineFramer::new();
        let mut out = Vec::new();
        f.push(
            b"\x00\xff garbage $GPGGA,1\x00,2\r\n$GPRMC,cut$GPZDA,ok\r\n",
            |l| out.push(l.to_vec()),
        );
        assert_eq!(out, vec![b"$GPZDA,ok".to_vec()]);
        let s = f.stats();
        assert_eq!((s.binary_lines, s.truncated_lines, s.lines), (1, 1, 1));
        assert_eq!(s.garbage_bytes, 11);
    }

    #[test]
    fn comment_lines_only_in_log_file_mode() {
        let data = b"# Notes: $GPGRS quoted\r\n#  $QZGSV,1\n$GPZDA,1\r\n x#$GPZDA,2\n";
        let mut f = LineFramer::for_log_files();
        let mut out = Vec::new();
        f.push(data, |l| out.push(l.to_vec()));
        assert_eq!(out, vec![b"$GPZDA,1".to_vec(), b"$GPZDA,2".to_vec()]);
        let mut f = LineFramer::new();
        let mut out = Vec::new();
        f.push(data, |l| out.push(l.to_vec()));
        assert_eq!(out.len(), 4, "serial mode keeps sentences after a '#'");
    }

    #[test]
    fn overlong_line_dropped_until_next_start() {
        let mut data = b"$GPGGA,".to_vec();
        data.extend(std::iter::repeat_n(b'9', 500));
        data.extend_from_slice(b"$GPRMC,next\r\n");
        let mut long_exact = b"$".to_vec();
        long_exact.extend(std::iter::repeat_n(b'X', MAX_LINE - 1));
        long_exact.extend_from_slice(b"\r\n");
        data.extend_from_slice(&long_exact);
        let mut f = LineFramer::new();
        let mut out = Vec::new();
        f.push(&data, |l| out.push(l.to_vec()));
        assert_eq!(out.len(), 2);
        assert_eq!(out[0], b"$GPRMC,next");
        assert_eq!(
            out[1].len(),
            MAX_LINE,
            "a line of exactly MAX_LINE bytes is kept"
        );
        assert_eq!(f.stats().overlong_lines, 1);
    }
}
