//! Where the service's log records go: the `tracing` subscriber that [`super::run`] installs.
//!
//! Library code logs through `tracing`'s macros and never chooses a destination; only the
//! service's entry calls [`init`]. Under systemd the records go to journald's native protocol
//! (so priorities and structured fields survive as journal fields); a hand-started service, or
//! one in a container without journald, writes one line per record to stderr.

use tracing::{Event, Level, Subscriber};
use tracing_journald::{Priority, PriorityMappings};
use tracing_subscriber::filter::LevelFilter;
use tracing_subscriber::fmt::format::Writer;
use tracing_subscriber::fmt::{FmtContext, FormatEvent, FormatFields};
use tracing_subscriber::layer::SubscriberExt;
use tracing_subscriber::registry::LookupSpan;
use tracing_subscriber::util::SubscriberInitExt;

/// The journal's identifier for our records (`journalctl -t infraloc`), whatever the binary is
/// called on disk.
const IDENTIFIER: &str = "infraloc";

/// Install the global subscriber: journald when its socket answers, stderr otherwise, records at
/// INFO and above. A second call (a process that already installed one) changes nothing.
pub(crate) fn init() {
    // The journal keeps the syslog priorities the service always used (info = 6, not
    // tracing-journald's default of notice = 5), so `journalctl -p info` filters as before.
    let journald = tracing_journald::layer().ok().map(|l| {
        l.with_syslog_identifier(IDENTIFIER.into())
            .with_priority_mappings(PriorityMappings {
                error: Priority::Error,
                warn: Priority::Warning,
                info: Priority::Informational,
                debug: Priority::Debug,
                trace: Priority::Debug,
            })
    });
    let stderr = journald.is_none().then(|| {
        tracing_subscriber::fmt::layer()
            .with_ansi(false)
            .with_writer(std::io::stderr)
            .event_format(OneLine)
    });
    let _ = tracing_subscriber::registry()
        .with(LevelFilter::INFO)
        .with(journald)
        .with(stderr)
        .try_init();
}

/// The stderr format, `infraloc[PID] LEVEL: message key=value…`, one line per record: a
/// message that carries a newline (an error listing several problems) is folded, so that line
/// oriented readers (grep, a log file's tail) see one record per line.
struct OneLine;

impl<S, N> FormatEvent<S, N> for OneLine
where
    S: Subscriber + for<'a> LookupSpan<'a>,
    N: for<'a> FormatFields<'a> + 'static,
{
    fn format_event(
        &self,
        ctx: &FmtContext<'_, S, N>,
        mut writer: Writer<'_>,
        event: &Event<'_>,
    ) -> std::fmt::Result {
        let mut fields = String::new();
        ctx.format_fields(Writer::new(&mut fields), event)?;
        writeln!(
            writer,
            "{IDENTIFIER}[{}] {}: {}",
            std::process::id(),
            tag(*event.metadata().level()),
            fields.replace('\n', " ")
        )
    }
}

/// The level words of the stderr format (syslog's, as the service printed them before).
fn tag(level: Level) -> &'static str {
    match level {
        Level::ERROR => "error",
        Level::WARN => "warning",
        Level::INFO => "info",
        Level::DEBUG => "debug",
        Level::TRACE => "trace",
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io;
    use std::sync::{Arc, Mutex};

    /// A writer the fmt layer can hand out, collecting everything into one buffer.
    #[derive(Clone, Default)]
    struct Buf(Arc<Mutex<Vec<u8>>>);

    impl io::Write for Buf {
        fn write(&mut self, b: &[u8]) -> io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(b);
            Ok(b.len())
        }
        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn stderr_lines_keep_the_old_format_and_fold_newlines() {
        let buf = Buf::default();
        let b2 = buf.clone();
        let subscriber = tracing_subscriber::registry().with(
            tracing_subscriber::fmt::layer()
                .with_ansi(false)
                .with_writer(move || b2.clone())
                .event_format(OneLine),
        );
        tracing::subscriber::with_default(subscriber, || {
            tracing::warn!("config: one\ntwo");
            tracing::info!(failures = 2, "retry");
        });
        let out = String::from_utf8(buf.0.lock().unwrap().clone()).unwrap();
        let pid = std::process::id();
        assert_eq!(
            out,
            format!("infraloc[{pid}] warning: config: one two\ninfraloc[{pid}] info: retry failures=2\n")
        );
    }
}
