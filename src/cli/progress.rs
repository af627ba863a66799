//! Stage progress for `localize` and `demo` on a terminal: one status line on stderr, redrawn in
//! place while the pipeline runs and erased when it ends. When stderr is not a terminal (tests,
//! systemd, pipes) nothing at all is written, so logs hold only the result and error lines.

use std::io::Write;
use std::sync::mpsc::{channel, Receiver, RecvTimeoutError};
use std::time::{Duration, Instant};

/// How often the line is redrawn between events: the `mi` stage reports nothing while it
/// runs (it is most of the time), and a frozen clock would look like a hang.
const REDRAW: Duration = Duration::from_millis(250);

/// Carriage return + ANSI "erase to end of line": the status line is rewritten, not appended.
const CLEAR: &str = "\r\x1b[K";

/// The status line `now_s` seconds into a run whose stages started at `starts` (name, seconds since
/// the run started, in order): the total time, then each stage with its duration, the last one
/// still running.
pub(crate) fn render(starts: &[(String, f64)], now_s: f64) -> String {
    let stages: Vec<String> = starts
        .iter()
        .enumerate()
        .map(|(i, (name, t))| {
            let end = starts.get(i + 1).map_or(now_s, |next| next.1);
            format!("{name} {:.1} s", (end - t).max(0.0))
        })
        .collect();
    format!("{CLEAR}{now_s:>5.1} s  {} …", stages.join(" · "))
}

/// Run `f` with a progress callback (told each stage's name as it starts) that draws the status
/// line on `out` when `is_terminal`, erasing it before returning; when not `is_terminal`, `f` gets
/// a no-op callback and `out` is never written. The check is the caller's so that a test can
/// hand in a buffer as either.
pub(crate) fn with_progress<W: Write + Send, T>(
    out: W,
    is_terminal: bool,
    f: impl FnOnce(&dyn Fn(&str)) -> T,
) -> T {
    if !is_terminal {
        return f(&|_| {});
    }
    let start = Instant::now();
    let (tx, rx) = channel();
    std::thread::scope(|s| {
        s.spawn(move || draw(out, rx, start));
        let progress = move |stage: &str| {
            // The drawing thread only stops once this sender is gone, so it cannot be missing.
            let _ = tx.send((stage.to_string(), start.elapsed().as_secs_f64()));
        };
        let result = f(&progress);
        // Dropping the sender ends the drawing thread, which the scope then joins: the line is
        // erased before the caller prints the result or the error.
        drop(progress);
        result
    })
}

/// The drawing thread: redraw on each event and every [`REDRAW`], erase when the sender is gone.
fn draw<W: Write>(mut out: W, rx: Receiver<(String, f64)>, start: Instant) {
    let mut starts = Vec::new();
    loop {
        match rx.recv_timeout(REDRAW) {
            Ok(event) => starts.push(event),
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => break,
        }
        if !starts.is_empty() {
            // Progress is cosmetic: a terminal that refuses writes must not fail the run.
            let _ = out.write_all(render(&starts, start.elapsed().as_secs_f64()).as_bytes());
            let _ = out.flush();
        }
    }
    if !starts.is_empty() {
        let _ = out.write_all(CLEAR.as_bytes());
        let _ = out.flush();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn starts(v: &[(&str, f64)]) -> Vec<(String, f64)> {
        v.iter().map(|(n, t)| (n.to_string(), *t)).collect()
    }

    #[test]
    fn render_gives_each_stage_its_duration_and_the_last_one_its_time_so_far() {
        let line = render(
            &starts(&[("capture", 0.0), ("prior", 0.4), ("localize", 1.5)]),
            7.5,
        );
        assert_eq!(
            line,
            "\r\x1b[K  7.5 s  capture 0.4 s · prior 1.1 s · localize 6.0 s …"
        );
    }

    /// The bytes `with_progress` writes for a run of two stages, checking `f`'s result comes back.
    fn two_stage_run(is_terminal: bool) -> Vec<u8> {
        let mut buf = Vec::new();
        let r = with_progress(&mut buf, is_terminal, |p| {
            p("capture");
            p("localize");
            42
        });
        assert_eq!(r, 42);
        buf
    }

    #[test]
    fn a_non_terminal_gets_no_progress_bytes() {
        let buf = two_stage_run(false);
        assert!(buf.is_empty(), "{:?}", String::from_utf8_lossy(&buf));
    }

    #[test]
    fn a_terminal_sees_the_stages_and_the_line_is_erased_at_the_end() {
        let text = String::from_utf8(two_stage_run(true)).unwrap();
        assert!(
            text.contains("capture") && text.contains("localize"),
            "{text:?}"
        );
        assert!(text.ends_with(CLEAR), "not erased: {text:?}");
    }
}
