//! GNSS I/O shell: the serial receiver reader (reconnecting, with a status), and acquisition of the
//! position prior from the configured source (NMEA file, serial receiver, or fixed position).
//! All parsing and estimation is in the pure [`crate::gnss`] module; this file owns the device,
//! the files and the clock.

use crate::config::{GpsConfig, GpsSourceKind};
use crate::error::{Error, Result};
use crate::gnss::{DecodeStats, Decoder, Fix, PriorEstimator, PriorOutcome, PriorSettings};
use serde::Serialize;
use std::io::{ErrorKind, Read};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::thread;
use std::time::{Duration, Instant};

/// One blocking read waits at most this long, so status and stop requests stay responsive.
pub(crate) const READ_TIMEOUT: Duration = Duration::from_millis(200);
/// First reconnect delay; doubled per failed attempt up to the configured maximum.
pub(crate) const RECONNECT_INITIAL: Duration = Duration::from_millis(250);
/// No byte for this long on an open port: the status says "no data".
pub(crate) const NO_DATA_AFTER: Duration = Duration::from_secs(5);
/// A fix older than this no longer counts as "fix" in the status.
pub(crate) const FIX_STALE_AFTER: Duration = Duration::from_secs(5);
/// Read buffer size (a few NMEA lines; the framer copes with any chunking).
const READ_CHUNK: usize = 256;

/// Serial reader settings.
#[derive(Debug, Clone)]
pub struct SerialSettings {
    /// Device path, e.g. `/dev/ttyACM0` (or a stable `/dev/serial/by-id/…` link).
    pub device: String,
    /// Baud rate.
    pub baud: u32,
    /// Upper bound of the reconnect back-off.
    pub reconnect_max: Duration,
}

/// What the receiver link is doing, worst first.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum GpsState {
    /// Never opened yet; attempts are failing (device absent, permission…).
    Connecting,
    /// Was open and got lost (unplugged, I/O error); retrying with back-off.
    Reconnecting,
    /// Open, but no bytes for `NO_DATA_AFTER` (wrong baud? receiver silent?).
    NoData,
    /// Sentences arrive but no valid fix recently (no sky view, cold start, antenna fault).
    NoFix,
    /// A valid fix within `FIX_STALE_AFTER`.
    Fix,
}

/// Receiver status, as `infraloc status` shows it.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub struct GpsStatus {
    /// Device path currently in use.
    pub device: String,
    /// State.
    pub state: GpsState,
    /// One line for a technician, e.g. "no fix for 3 h 02 min on /dev/ttyACM0".
    pub summary: String,
    /// How long the state has lasted, seconds.
    pub state_for_s: f64,
    /// Receiver time of the last fix (ISO 8601).
    pub last_fix_time: Option<String>,
    /// Host seconds since the last fix.
    pub last_fix_age_s: Option<f64>,
    /// Fixes since start.
    pub fixes: u64,
    /// Successful reconnects after a loss.
    pub reconnects: u64,
    /// Last open/read error.
    pub last_error: Option<String>,
    /// Decoder counters (sentences, checksum errors…).
    pub decode: DecodeStats,
}

fn human_duration(d: Duration) -> String {
    let s = d.as_secs();
    match s {
        0..=59 => format!("{s} s"),
        60..=3599 => format!("{} min {:02} s", s / 60, s % 60),
        _ => format!("{} h {:02} min", s / 3600, (s % 3600) / 60),
    }
}

/// Where the device is: a fixed path, or a resolver asked again before each (re)connect (e.g.
/// scanning `/dev/serial/by-id/`).
pub(crate) type Resolver = Box<dyn FnMut() -> String + Send>;

/// The reconnecting serial reader. Drive it with [`SerialReader::poll`] (or [`spawn`] a thread).
pub struct SerialReader {
    settings: SerialSettings,
    resolve: Resolver,
    device: String,
    port: Option<Box<dyn serialport::SerialPort>>,
    decoder: Decoder,
    ever_connected: bool,
    backoff: Duration,
    next_attempt: Instant,
    state_since: Instant,
    last_byte: Option<Instant>,
    last_fix: Option<(Instant, Option<String>)>,
    reconnects: u64,
    last_error: Option<String>,
    buf: [u8; READ_CHUNK],
}

impl SerialReader {
    /// A reader for the configured device path.
    pub fn new(settings: SerialSettings) -> Self {
        let dev = settings.device.clone();
        Self::with_resolver(settings, Box::new(move || dev.clone()))
    }

    /// A reader that asks `resolve` for the device path before every connection attempt.
    pub(crate) fn with_resolver(settings: SerialSettings, resolve: Resolver) -> Self {
        let now = Instant::now();
        SerialReader {
            device: settings.device.clone(),
            settings,
            resolve,
            port: None,
            decoder: Decoder::new(),
            ever_connected: false,
            backoff: RECONNECT_INITIAL,
            next_attempt: now,
            state_since: now,
            last_byte: None,
            last_fix: None,
            reconnects: 0,
            last_error: None,
            buf: [0; READ_CHUNK],
        }
    }

    /// Whether the port is open.
    pub fn is_connected(&self) -> bool {
        self.port.is_some()
    }

    fn lose(&mut self, why: String) {
        self.port = None;
        self.last_error = Some(why);
        self.decoder.reset_line();
        self.backoff = RECONNECT_INITIAL;
        self.next_attempt = Instant::now() + self.backoff;
        self.state_since = Instant::now();
    }

    fn try_open(&mut self) {
        self.device = (self.resolve)();
        let opened = serialport::new(&self.device, self.settings.baud)
            .timeout(READ_TIMEOUT)
            .open();
        let now = Instant::now();
        match opened {
            Ok(p) => {
                if self.ever_connected {
                    self.reconnects += 1;
                }
                self.ever_connected = true;
                self.port = Some(p);
                self.backoff = RECONNECT_INITIAL;
                self.state_since = now;
                self.last_byte = None;
                self.decoder.reset_line();
            }
            Err(e) => {
                self.last_error = Some(format!("open {}: {e}", self.device));
                self.next_attempt = now + self.backoff;
                self.backoff =
                    (self.backoff * 2).min(self.settings.reconnect_max.max(RECONNECT_INITIAL));
            }
        }
    }

    /// One unit of work: a read (≤ `READ_TIMEOUT`) when connected, else a connection attempt
    /// or a wait of at most `READ_TIMEOUT` for the next one. Every fix decoded goes to `on_fix`.
    /// Never fails: problems become the status.
    pub fn poll(&mut self, mut on_fix: impl FnMut(Fix)) {
        let Some(port) = self.port.as_mut() else {
            let now = Instant::now();
            if now >= self.next_attempt {
                self.try_open();
            } else {
                thread::sleep((self.next_attempt - now).min(READ_TIMEOUT));
            }
            return;
        };
        match port.read(&mut self.buf) {
            Ok(0) => self.lose(format!("{}: end of stream", self.device)),
            Ok(n) => {
                let now = Instant::now();
                self.last_byte = Some(now);
                let last_fix = &mut self.last_fix;
                self.decoder.push(&self.buf[..n], |f| {
                    *last_fix = Some((now, f.iso_time()));
                    on_fix(f);
                });
            }
            Err(e) if e.kind() == ErrorKind::TimedOut || e.kind() == ErrorKind::Interrupted => {
                // Some USB-serial drivers keep a vanished device's fd "readable" with timeouts
                // only: check that the device node still exists.
                if !Path::new(&self.device).exists() {
                    self.lose(format!("{}: device node disappeared", self.device));
                }
            }
            Err(e) => self.lose(format!("read {}: {e}", self.device)),
        }
    }

    /// The current status.
    pub fn status(&self) -> GpsStatus {
        let now = Instant::now();
        let fix_age = self.last_fix.as_ref().map(|(t, _)| now - *t);
        let (state, summary, since) = if self.port.is_none() {
            let st = if self.ever_connected {
                GpsState::Reconnecting
            } else {
                GpsState::Connecting
            };
            let err = self.last_error.as_deref().unwrap_or("not opened yet");
            let verb = if self.ever_connected {
                "reconnecting"
            } else {
                "connecting"
            };
            (
                st,
                format!(
                    "{verb} to {} for {} ({err})",
                    self.device,
                    human_duration(now - self.state_since)
                ),
                self.state_since,
            )
        } else {
            let data_since = self.last_byte.unwrap_or(self.state_since);
            if now - data_since >= NO_DATA_AFTER {
                (
                    GpsState::NoData,
                    format!(
                        "no data from {} for {}",
                        self.device,
                        human_duration(now - data_since)
                    ),
                    data_since,
                )
            } else if fix_age.is_some_and(|a| a < FIX_STALE_AFTER) {
                let since = self.last_fix.as_ref().map_or(now, |(t, _)| *t);
                (GpsState::Fix, format!("fix on {}", self.device), since)
            } else {
                // Without a fix since connecting, or since the last fix went stale.
                let since = match &self.last_fix {
                    Some((t, _)) if *t > self.state_since => *t,
                    _ => self.state_since,
                };
                (
                    GpsState::NoFix,
                    format!(
                        "no fix for {} on {}",
                        human_duration(now - since),
                        self.device
                    ),
                    since,
                )
            }
        };
        GpsStatus {
            device: self.device.clone(),
            state,
            summary,
            state_for_s: (now - since).as_secs_f64(),
            last_fix_time: self.last_fix.as_ref().and_then(|(_, t)| t.clone()),
            last_fix_age_s: fix_age.map(|a| a.as_secs_f64()),
            fixes: self.decoder.stats().fixes,
            reconnects: self.reconnects,
            last_error: self.last_error.clone(),
            decode: self.decoder.stats(),
        }
    }
}

/// A reader running in its own thread.
pub struct ReaderHandle {
    /// Latest status (updated after every poll).
    pub status: Arc<Mutex<GpsStatus>>,
    /// Decoded fixes.
    pub fixes: mpsc::Receiver<Fix>,
    stop: Arc<AtomicBool>,
    join: Option<thread::JoinHandle<()>>,
}

impl ReaderHandle {
    /// A snapshot of the status.
    pub fn status(&self) -> Option<GpsStatus> {
        self.status.lock().ok().map(|s| s.clone())
    }

    /// Stop the thread and wait for it (at most one poll, ≤ `READ_TIMEOUT`).
    pub fn stop(mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(j) = self.join.take() {
            let _ = j.join();
        }
    }
}

impl Drop for ReaderHandle {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

/// Run `reader` on a thread until the handle is stopped or dropped.
pub fn spawn(mut reader: SerialReader) -> ReaderHandle {
    let status = Arc::new(Mutex::new(reader.status()));
    let stop = Arc::new(AtomicBool::new(false));
    let (tx, rx) = mpsc::channel();
    let (st, sp) = (status.clone(), stop.clone());
    let join = thread::Builder::new()
        .name("gps-serial".into())
        .spawn(move || {
            let mut batch = Vec::new();
            while !sp.load(Ordering::Relaxed) {
                reader.poll(|f| batch.push(f));
                // Publish the status before the fixes it counts: a consumer that has received a
                // fix then sees a status that includes it (sending first let `status().fixes`
                // lag the fixes received: the pty test's 49-of-50 failures).
                if let Ok(mut s) = st.lock() {
                    *s = reader.status();
                }
                for f in batch.drain(..) {
                    let _ = tx.send(f);
                }
            }
        })
        .ok();
    ReaderHandle {
        status,
        fixes: rx,
        stop,
        join,
    }
}

/// Decode an NMEA log file completely: every fix in order, plus the counters.
pub fn decode_file(path: &Path) -> Result<(Vec<Fix>, DecodeStats)> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let mut d = Decoder::for_log_files();
    let mut fixes = Vec::new();
    d.push(&bytes, |f| fixes.push(f));
    d.finish(|f| fixes.push(f));
    Ok((fixes, d.stats()))
}

/// A configured duration in seconds, or a config error naming the key.
fn secs(key: &str, v: f64) -> Result<Duration> {
    Duration::try_from_secs_f64(v)
        .map_err(|_| Error::config("[gps]", format!("{key} = {v} is not a usable duration")))
}

fn prior_settings(g: &GpsConfig) -> PriorSettings {
    PriorSettings {
        window_s: g.window_s,
        max_hdop: g.max_hdop,
        min_fixes: g.min_fixes,
    }
}

/// Acquire the position prior from the configured source: average an NMEA file's last window;
/// or read the serial receiver until a window of fixes is collected or `timeout-s` passes; or
/// take the fixed position. Without a usable fix the surveyed `fallback-wgs84` is returned with
/// the reason. Only unusable configuration is an error.
pub fn acquire_prior(g: &GpsConfig) -> Result<PriorOutcome> {
    acquire_prior_unless(g, &AtomicBool::new(false))
}

/// [`acquire_prior`] that gives up once `cancel` is set: a serial receiver is read at most
/// `READ_TIMEOUT` at a time and the flag checked between reads (the node acquires the prior
/// while it captures, and a failed capture ends the attempt). What a cancelled acquisition
/// returns is the outcome so far; the caller discards it.
pub fn acquire_prior_unless(g: &GpsConfig, cancel: &AtomicBool) -> Result<PriorOutcome> {
    let fallback = g.fallback_wgs84.map(|p| (p, g.fallback_sigma_m));
    let mut est = PriorEstimator::new(prior_settings(g));
    match g.source {
        GpsSourceKind::Fixed => {
            let [lat, lon] = g
                .fallback_wgs84
                .ok_or_else(|| Error::config("[gps]", "source = \"fixed\" needs fallback-wgs84"))?;
            Ok(PriorOutcome::Fixed {
                lat,
                lon,
                sigma_m: g.fallback_sigma_m,
            })
        }
        GpsSourceKind::NmeaFile => {
            let path = g
                .path
                .as_deref()
                .ok_or_else(|| Error::config("[gps]", "source = \"nmea-file\" needs path"))?;
            let (fixes, stats) = decode_file(path)?;
            for f in &fixes {
                est.push(f);
            }
            let why = format!("{}: {}", path.display(), stats.describe());
            Ok(est.outcome(fallback, &why))
        }
        GpsSourceKind::Serial => {
            let device = g
                .device
                .clone()
                .ok_or_else(|| Error::config("[gps]", "source = \"serial\" needs device"))?;
            let mut reader = SerialReader::new(SerialSettings {
                device,
                baud: g.baud,
                reconnect_max: secs("reconnect-max-s", g.reconnect_max_s)?,
            });
            let start = Instant::now();
            let timeout = secs("timeout-s", g.timeout_s)?;
            let window = secs("window-s", g.window_s)?;
            let mut first_kept: Option<Instant> = None;
            while start.elapsed() < timeout && !cancel.load(Ordering::Relaxed) {
                reader.poll(|f| {
                    if est.push(&f) && first_kept.is_none() {
                        first_kept = Some(Instant::now());
                    }
                });
                if first_kept.is_some_and(|t| t.elapsed() >= window) {
                    break;
                }
            }
            let st = reader.status();
            let why = format!(
                "after {:.0} s: {}; {}",
                start.elapsed().as_secs_f64(),
                st.summary,
                st.decode.describe()
            );
            Ok(est.outcome(fallback, &why))
        }
    }
}
