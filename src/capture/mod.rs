//! Frame capture (I/O shell): V4L2, Aravis (GigE Vision / USB3 Vision) and file sources, a
//! burst of frames spaced in time, and their temporal median.
//!
//! The pieces a camera cannot be present for are pure and tested on their own: format
//! conversion (`convert`), the median ([`median`]) and the capture loop, whose clock is
//! injected ([`Clock`]) so spacing and retry back-off are tested without sleeping.
//! `docs/capture.md` is the operator's view.

pub(crate) mod convert;
mod file;
pub mod median;

#[cfg(feature = "aravis")]
mod aravis;
#[cfg(feature = "v4l")]
mod v4l2;

#[cfg(feature = "aravis")]
pub use aravis::{AravisSettings, AravisSource};
pub(crate) use file::{load_gray, FileSource};
pub use median::temporal_median;
#[cfg(feature = "v4l")]
pub(crate) use v4l2::V4l2Source;

use crate::config::{CameraConfig, FrameSourceKind};
use crate::error::{Error, Result};
use image::GrayImage;
use std::fmt;
use std::time::{Duration, Instant, SystemTime};

/// One gray frame and when it was taken.
#[derive(Debug, Clone)]
pub struct Frame {
    /// The frame, converted to 8-bit gray.
    pub image: GrayImage,
    /// When the frame became available on this host (driver/transport timestamp where the
    /// source has one, else the time it was read).
    pub timestamp: SystemTime,
    /// The source's frame counter (driver sequence, GigE Vision block id, file index).
    pub sequence: u64,
}

/// What went wrong with a source, so the capture loop can decide to retry.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fault {
    /// The device (or file) is not there or cannot be opened.
    Absent,
    /// No frame arrived within the timeout.
    Timeout,
    /// A frame arrived with fewer bytes than its geometry needs.
    Short,
    /// A frame arrived but does not decode, or the driver flagged it as damaged.
    Corrupt,
    /// The device works but cannot deliver what the config asks (format, region): retrying
    /// cannot help.
    Unsupported,
    /// Any other operating-system or transport error.
    Io,
}

impl Fault {
    /// Whether another attempt may succeed (cables get replugged, packets get lost).
    pub(crate) fn is_transient(self) -> bool {
        !matches!(self, Fault::Unsupported)
    }

    /// Whether the source should be closed and reopened before the next attempt.
    fn needs_reopen(self) -> bool {
        matches!(self, Fault::Absent | Fault::Timeout | Fault::Io)
    }
}

impl fmt::Display for Fault {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Fault::Absent => "device absent",
            Fault::Timeout => "timeout",
            Fault::Short => "short frame",
            Fault::Corrupt => "corrupt frame",
            Fault::Unsupported => "unsupported setting",
            Fault::Io => "I/O error",
        })
    }
}

/// A source failure: its kind and the source's own words (OS error text, driver status).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct GrabError {
    /// The kind, for the retry decision.
    pub fault: Fault,
    /// One line for the operator.
    pub detail: String,
}

impl GrabError {
    /// Shorthand constructor.
    pub(crate) fn new(fault: Fault, detail: impl Into<String>) -> Self {
        GrabError {
            fault,
            detail: detail.into(),
        }
    }

    /// From an OS error: "not found"/"no device" map to [`Fault::Absent`], a timeout to
    /// [`Fault::Timeout`], the rest to [`Fault::Io`].
    pub(crate) fn from_io(e: &std::io::Error) -> Self {
        use std::io::ErrorKind;
        // ENODEV/ENXIO: the node exists but the camera behind it is gone (unplugged USB).
        const ENXIO: i32 = 6;
        const ENODEV: i32 = 19;
        let fault = match e.kind() {
            ErrorKind::NotFound | ErrorKind::PermissionDenied => Fault::Absent,
            ErrorKind::TimedOut => Fault::Timeout,
            _ if matches!(e.raw_os_error(), Some(ENXIO | ENODEV)) => Fault::Absent,
            _ => Fault::Io,
        };
        GrabError::new(fault, e.to_string())
    }
}

impl From<convert::ConvertError> for GrabError {
    fn from(e: convert::ConvertError) -> Self {
        let fault = match e {
            convert::ConvertError::Short { .. } => Fault::Short,
            convert::ConvertError::Corrupt(_) => Fault::Corrupt,
        };
        GrabError::new(fault, e.to_string())
    }
}

/// A camera or replay source. The capture loop calls `open`, `grab` repeatedly, `close`; after
/// a failure it may `close` and `open` again.
pub trait FrameSource {
    /// The device as the operator configured it (`/dev/video0`, a camera id, a path): every
    /// capture error names it.
    fn device(&self) -> &str;
    /// Open the device and start streaming.
    fn open(&mut self) -> Result<(), GrabError>;
    /// The next frame, waiting at most `timeout`.
    fn grab(&mut self, timeout: Duration) -> Result<Frame, GrabError>;
    /// Stop streaming and release the device (idempotent).
    fn close(&mut self);
}

/// Monotonic time and sleeping, injected so tests run the capture schedule without waiting.
pub trait Clock {
    /// Time since an arbitrary fixed origin.
    fn now(&self) -> Duration;
    /// Block for `d`.
    fn sleep(&self, d: Duration);
}

/// The real clock.
#[derive(Debug, Clone, Copy)]
pub struct SystemClock {
    origin: Instant,
}

impl Default for SystemClock {
    fn default() -> Self {
        SystemClock {
            origin: Instant::now(),
        }
    }
}

impl Clock for SystemClock {
    fn now(&self) -> Duration {
        self.origin.elapsed()
    }
    fn sleep(&self, d: Duration) {
        std::thread::sleep(d)
    }
}

/// Bounded retry with exponential back-off.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RetryPolicy {
    /// Attempts per frame (≥ 1), the first included.
    pub attempts: u32,
    /// Wait after the first failure; doubled after each further failure.
    pub backoff: Duration,
    /// Upper bound of the wait.
    pub max_backoff: Duration,
}

/// Longest wait between attempts whatever the config says: the node should report a dead
/// camera within a minute or so, not back off for hours.
const MAX_BACKOFF: Duration = Duration::from_secs(30);

/// How a burst is captured.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CaptureSettings {
    /// Frames returned (≥ 1).
    pub frame_count: u32,
    /// Spacing of the burst: grab `i` starts `i × interval` after the first frame arrived.
    pub interval: Duration,
    /// Frames discarded after each open while auto-exposure settles.
    pub settle_frames: u32,
    /// Per-frame timeout.
    pub timeout: Duration,
    /// Retry policy for open and grab faults.
    pub retry: RetryPolicy,
}

impl CaptureSettings {
    /// The `[camera]` table's capture keys.
    pub(crate) fn from_config(c: &CameraConfig) -> CaptureSettings {
        CaptureSettings {
            frame_count: c.frame_count,
            interval: Duration::from_millis(c.frame_interval_ms),
            settle_frames: c.settle_frames,
            timeout: Duration::from_millis(c.timeout_ms),
            retry: RetryPolicy {
                attempts: c.retry_attempts.max(1),
                backoff: Duration::from_millis(c.retry_backoff_ms),
                max_backoff: MAX_BACKOFF,
            },
        }
    }
}

/// A captured burst.
#[derive(Debug, Clone)]
pub struct Capture {
    /// The frames, in capture order.
    pub frames: Vec<Frame>,
    /// Their per-pixel temporal median.
    pub median: GrayImage,
}

/// The source named by the config (not yet opened). A source kind compiled out of this build
/// is an error that says which cargo feature it needs.
pub(crate) fn source_from_config(c: &CameraConfig) -> Result<Box<dyn FrameSource>> {
    match c.source {
        FrameSourceKind::File => {
            let path = c.frames.as_ref().ok_or_else(|| {
                Error::FrameSource("[camera] source = \"file\" needs frames".into())
            })?;
            Ok(Box::new(FileSource::new(path)))
        }
        #[cfg(feature = "v4l")]
        FrameSourceKind::V4l2 => Ok(Box::new(V4l2Source::from_config(c)?)),
        #[cfg(feature = "aravis")]
        FrameSourceKind::Aravis => Ok(Box::new(AravisSource::from_config(c)?)),
        // Config::load refuses these first (exit 78); a caller that built its CameraConfig
        // itself gets the same line.
        #[allow(unreachable_patterns)]
        other => Err(Error::FrameSource(other.missing_backend_problem())),
    }
}

/// Open `source`, discard the settle frames, grab `frame_count` frames spaced `interval` apart
/// (each with bounded retries), close it, and return the frames with their temporal median.
///
/// A fault that persists through every attempt becomes one error line naming the device and
/// what happened, e.g. `capture: camera /dev/video0: No such file or directory (os error 2)
/// [device absent; gave up after 3 attempts]`.
pub fn capture(
    source: &mut dyn FrameSource,
    settings: &CaptureSettings,
    clock: &dyn Clock,
) -> Result<Capture> {
    if settings.frame_count == 0 {
        return Err(Error::stage(
            crate::stage::StageName::Capture,
            "frame-count must be at least 1",
        ));
    }
    let mut session = Session {
        source,
        settings,
        clock,
        open: false,
    };
    let result = session.burst();
    session.source.close();
    let frames = result?;
    let images: Vec<GrayImage> = frames.iter().map(|f| f.image.clone()).collect();
    let median = temporal_median(&images)?;
    Ok(Capture { frames, median })
}

/// One capture run: the source and whether it is currently open (and settled).
struct Session<'a> {
    source: &'a mut dyn FrameSource,
    settings: &'a CaptureSettings,
    clock: &'a dyn Clock,
    open: bool,
}

impl Session<'_> {
    fn burst(&mut self) -> Result<Vec<Frame>> {
        let n = self.settings.frame_count as usize;
        let mut frames = Vec::with_capacity(n);
        let mut start = None;
        for i in 0..n {
            if let Some(t0) = start {
                // Schedule against the first grab so spacing does not drift with grab time.
                let due = t0 + self.settings.interval * i as u32;
                let now = self.clock.now();
                if due > now {
                    self.clock.sleep(due - now);
                }
            }
            let frame = self.grab_with_retry()?;
            if start.is_none() {
                start = Some(self.clock.now());
            }
            frames.push(frame);
        }
        Ok(frames)
    }

    /// Open (and settle) the source if needed.
    fn ensure_open(&mut self) -> Result<(), GrabError> {
        if self.open {
            return Ok(());
        }
        self.source.open()?;
        self.open = true;
        for _ in 0..self.settings.settle_frames {
            self.source.grab(self.settings.timeout)?;
        }
        Ok(())
    }

    fn grab_with_retry(&mut self) -> Result<Frame> {
        let retry = self.settings.retry;
        let attempts = retry.attempts.max(1);
        let mut backoff = retry.backoff;
        let mut attempt = 0;
        let last = loop {
            attempt += 1;
            let err = match self
                .ensure_open()
                .and_then(|_| self.source.grab(self.settings.timeout))
            {
                Ok(frame) => return Ok(frame),
                Err(e) => e,
            };
            if err.fault.needs_reopen() || !self.open {
                self.source.close();
                self.open = false;
            }
            if !err.fault.is_transient() || attempt >= attempts {
                break err;
            }
            self.clock.sleep(backoff);
            backoff = (backoff * 2).min(retry.max_backoff);
        };
        Err(Error::stage(
            crate::stage::StageName::Capture,
            format!(
                "camera {}: {} [{}; gave up after {attempt} attempt{}]",
                self.source.device(),
                last.detail,
                last.fault,
                if attempt == 1 { "" } else { "s" }
            ),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::cell::{Cell, RefCell};
    use std::collections::VecDeque;
    use std::rc::Rc;

    /// A clock that only moves when slept on, recording every sleep.
    #[derive(Default)]
    struct FakeClock {
        t: Cell<Duration>,
        sleeps: RefCell<Vec<Duration>>,
    }

    impl Clock for FakeClock {
        fn now(&self) -> Duration {
            self.t.get()
        }
        fn sleep(&self, d: Duration) {
            self.t.set(self.t.get() + d);
            self.sleeps.borrow_mut().push(d);
        }
    }

    /// A scripted source: each open/grab pops the next scripted outcome; grabs take
    /// `grab_cost` of fake time. Records the fake time of every successful grab.
    struct Scripted<'c> {
        clock: &'c FakeClock,
        opens: VecDeque<Result<(), GrabError>>,
        grabs: VecDeque<Result<u8, GrabError>>,
        grab_cost: Duration,
        log: Rc<RefCell<Vec<String>>>,
    }

    impl FrameSource for Scripted<'_> {
        fn device(&self) -> &str {
            "/dev/video7"
        }
        fn open(&mut self) -> Result<(), GrabError> {
            self.log.borrow_mut().push("open".into());
            self.opens.pop_front().unwrap_or(Ok(()))
        }
        fn grab(&mut self, _timeout: Duration) -> Result<Frame, GrabError> {
            self.clock.t.set(self.clock.t.get() + self.grab_cost);
            let v = self.grabs.pop_front().unwrap_or(Ok(0))?;
            self.log
                .borrow_mut()
                .push(format!("grab {v} @{}ms", self.clock.now().as_millis()));
            Ok(Frame {
                image: GrayImage::from_pixel(4, 3, image::Luma([v])),
                timestamp: SystemTime::UNIX_EPOCH,
                sequence: v as u64,
            })
        }
        fn close(&mut self) {
            self.log.borrow_mut().push("close".into());
        }
    }

    fn settings(n: u32, settle: u32, attempts: u32) -> CaptureSettings {
        CaptureSettings {
            frame_count: n,
            interval: Duration::from_millis(1000),
            settle_frames: settle,
            timeout: Duration::from_millis(500),
            retry: RetryPolicy {
                attempts,
                backoff: Duration::from_millis(100),
                max_backoff: Duration::from_millis(250),
            },
        }
    }

    fn scripted<'c>(clock: &'c FakeClock, grabs: Vec<Result<u8, GrabError>>) -> Scripted<'c> {
        Scripted {
            clock,
            opens: VecDeque::new(),
            grabs: grabs.into(),
            grab_cost: Duration::from_millis(30),
            log: Rc::default(),
        }
    }

    #[test]
    fn settles_then_spaces_frames_and_takes_median() {
        let clock = FakeClock::default();
        // Two settle frames (99 — must not appear), then 5 frames with one outlier.
        let mut src = scripted(
            &clock,
            vec![Ok(99), Ok(99), Ok(10), Ok(200), Ok(12), Ok(11), Ok(13)],
        );
        let cap = capture(&mut src, &settings(5, 2, 3), &clock).unwrap();
        let seq: Vec<u64> = cap.frames.iter().map(|f| f.sequence).collect();
        assert_eq!(seq, [10, 200, 12, 11, 13]);
        assert!(cap.median.pixels().all(|p| p[0] == 12));
        let log = src.log.borrow();
        // Grabs start 1000 ms apart (first frame ends at 4×30 = 120 ms after settling), the
        // grab time is absorbed by the schedule rather than added to it.
        assert_eq!(
            *log,
            [
                "open",
                "grab 99 @30ms",
                "grab 99 @60ms",
                "grab 10 @90ms",
                "grab 200 @1120ms",
                "grab 12 @2120ms",
                "grab 11 @3120ms",
                "grab 13 @4120ms",
                "close"
            ]
        );
        assert_eq!(clock.sleeps.borrow().len(), 4);
    }

    #[test]
    fn transient_faults_retry_with_backoff_then_succeed() {
        let clock = FakeClock::default();
        let mut src = scripted(
            &clock,
            vec![
                Err(GrabError::new(
                    Fault::Corrupt,
                    "corrupt frame: bad huffman code",
                )),
                Err(GrabError::new(Fault::Timeout, "no frame within 500 ms")),
                Ok(42),
            ],
        );
        let cap = capture(&mut src, &settings(1, 0, 3), &clock).unwrap();
        assert_eq!(cap.frames[0].sequence, 42);
        // Back-off 100 ms, then 200 ms; a corrupt frame keeps the stream, a timeout reopens.
        // Fake time: three grabs of 30 ms plus 300 ms of back-off.
        assert_eq!(
            *clock.sleeps.borrow(),
            [Duration::from_millis(100), Duration::from_millis(200)]
        );
        assert_eq!(
            *src.log.borrow(),
            ["open", "close", "open", "grab 42 @390ms", "close"]
        );
    }

    #[test]
    fn absent_device_gives_up_with_one_line_naming_it() {
        let clock = FakeClock::default();
        let mut src = scripted(&clock, vec![]);
        let enoent = std::io::Error::from_raw_os_error(2);
        src.opens = std::iter::repeat_with(|| Err(GrabError::from_io(&enoent)))
            .take(10)
            .collect();
        let e = capture(&mut src, &settings(3, 0, 4), &clock).unwrap_err();
        let s = e.to_string();
        assert_eq!(
            s,
            "capture: camera /dev/video7: No such file or directory (os error 2) \
             [device absent; gave up after 4 attempts]"
        );
        assert!(!s.contains('\n'));
        // 100, 200, then capped at 250 ms.
        assert_eq!(
            *clock.sleeps.borrow(),
            [100, 200, 250].map(Duration::from_millis)
        );
        assert_eq!(src.log.borrow().iter().filter(|l| *l == "open").count(), 4);
    }

    #[test]
    fn unsupported_is_not_retried() {
        let clock = FakeClock::default();
        let mut src = scripted(&clock, vec![]);
        src.opens = [Err(GrabError::new(
            Fault::Unsupported,
            "pixel format RGB3 is not one of GREY, Y16, YUYV, MJPG",
        ))]
        .into();
        let e = capture(&mut src, &settings(3, 0, 5), &clock).unwrap_err();
        assert!(e.to_string().contains("gave up after 1 attempt]"), "{e}");
        assert!(clock.sleeps.borrow().is_empty());
    }

    #[test]
    fn io_error_kinds_map_to_faults() {
        let f = |code| GrabError::from_io(&std::io::Error::from_raw_os_error(code)).fault;
        assert_eq!(f(2), Fault::Absent); // ENOENT
        assert_eq!(f(19), Fault::Absent); // ENODEV
        assert_eq!(f(110), Fault::Timeout); // ETIMEDOUT
        assert_eq!(f(5), Fault::Io); // EIO
    }

    #[test]
    fn file_source_needs_frames() {
        let c = CameraConfig {
            source: FrameSourceKind::File,
            frames: None,
            ..CameraConfig::default()
        };
        assert!(source_from_config(&c).is_err());
    }
}
