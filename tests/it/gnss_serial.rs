//! The serial reader over real pseudo-terminals (`serialport::TTYPort::pair()`):
//! (b) every gpsd log written byte by byte at real baud pacing gives exactly the fixes of the
//!     file decoder; (c) the device disappears and comes back at the same path → reconnect,
//!     visible in the status; garbage and over-long lines on the wire are survived.
//!
//! Pacing: one `write` per byte, scheduled at 10 bits/byte of the chosen baud. Each log gets the
//! lowest of 9600/38400/115200 baud that sends it in ≤ [`MAX_LOG_SECONDS`], and the logs run in
//! parallel (one pty each), so the whole test takes about that long.
//!
//! Skipped under qemu-user (`INFRALOC_QEMU=1`): qemu does not emulate the termios2 baud-rate
//! ioctls (TCGETS2) that opening a serial port needs.

use crate::common;

use infraloc::gnss::Fix;
use infraloc::gps_serial::{self, GpsState, SerialReader, SerialSettings};
use serialport::{SerialPort, TTYPort};
use std::io::Write;
use std::path::Path;
use std::thread;
use std::time::{Duration, Instant};

const MAX_LOG_SECONDS: f64 = 6.0;
const BAUDS: [u32; 3] = [9600, 38_400, 115_200];
const BITS_PER_BYTE: f64 = 10.0; // 8N1: start + 8 data + stop

fn skip_under_qemu() -> bool {
    if std::env::var_os("INFRALOC_QEMU").is_some_and(|v| v == "1") {
        common::skip(
            "gnss_serial",
            "INFRALOC_QEMU=1 (qemu-user lacks the TCGETS2 baud-rate ioctls)",
        );
        return true;
    }
    false
}

fn paced_write(master: &mut TTYPort, bytes: &[u8], baud: u32) {
    let byte_time = Duration::from_secs_f64(BITS_PER_BYTE / baud as f64);
    let start = Instant::now();
    for (i, b) in bytes.iter().enumerate() {
        let due = start + byte_time.mul_f64(i as f64);
        let now = Instant::now();
        if due > now {
            thread::sleep(due - now);
        }
        master.write_all(std::slice::from_ref(b)).unwrap();
    }
}

fn settings(device: &str, baud: u32) -> SerialSettings {
    SerialSettings {
        device: device.to_string(),
        baud,
        reconnect_max: Duration::from_millis(400),
    }
}

fn wait_for(what: &str, timeout: Duration, mut cond: impl FnMut() -> bool) {
    let start = Instant::now();
    while !cond() {
        assert!(start.elapsed() < timeout, "timed out waiting for {what}");
        thread::sleep(Duration::from_millis(20));
    }
}

/// Collect fixes until `n` arrived or nothing came for `gap`.
fn collect(rx: &std::sync::mpsc::Receiver<Fix>, n: usize, gap: Duration) -> Vec<Fix> {
    let mut v = Vec::new();
    while v.len() < n {
        match rx.recv_timeout(gap) {
            Ok(f) => v.push(f),
            Err(_) => break,
        }
    }
    v
}

#[test]
fn logs_over_pty_at_baud_pacing_equal_file_decode() {
    if skip_under_qemu() {
        return;
    }
    let logs = common::nmea_logs();
    let started = Instant::now();
    let workers: Vec<_> = logs
        .into_iter()
        .map(|log| {
            thread::spawn(move || {
                let bytes = std::fs::read(&log).unwrap();
                let (want, _) = gps_serial::decode_file(&log).unwrap();
                let baud = *BAUDS
                    .iter()
                    .find(|&&b| bytes.len() as f64 * BITS_PER_BYTE / b as f64 <= MAX_LOG_SECONDS)
                    .unwrap_or(&BAUDS[2]);
                let (mut master, slave) = TTYPort::pair().unwrap();
                master.set_timeout(Duration::from_secs(10)).unwrap();
                let path = slave.name().unwrap();
                let h = gps_serial::spawn(SerialReader::new(settings(&path, baud)));
                wait_for("port open", Duration::from_secs(5), || {
                    h.status().is_some_and(|s| s.state != GpsState::Connecting)
                });
                paced_write(&mut master, &bytes, baud);
                // A generous gap: on a loaded machine the reader thread can be starved for
                // seconds, and a short gap would end the collection before the last fix (a
                // really missing fix still fails, only later).
                let got = collect(&h.fixes, want.len(), Duration::from_secs(30));
                let st = h.status().unwrap();
                h.stop();
                drop(slave);
                let name = log.file_name().unwrap().to_string_lossy().to_string();
                assert_eq!(got.len(), want.len(), "{name}: fixes over the pty");
                assert_eq!(
                    got, want,
                    "{name}: fixes over the pty differ from the file decode"
                );
                assert_eq!(st.fixes as usize, want.len());
                (name, baud, bytes.len(), got.len())
            })
        })
        .collect();
    let mut total = 0;
    for w in workers {
        let (name, baud, n_bytes, n_fixes) = w.join().unwrap();
        eprintln!(
            "{name}: {n_bytes} bytes at {baud} baud → {n_fixes} fixes identical to the file decode"
        );
        total += n_fixes;
    }
    eprintln!("{total} fixes in {:.1} s", started.elapsed().as_secs_f64());
    assert!(total > 500);
}

fn make_link(link: &Path, target: &str) {
    let tmp = link.with_extension("new");
    let _ = std::fs::remove_file(&tmp);
    std::os::unix::fs::symlink(target, &tmp).unwrap();
    std::fs::rename(&tmp, link).unwrap(); // atomic replace, like udev
}

#[test]
fn device_disappears_and_comes_back() {
    if skip_under_qemu() {
        return;
    }
    let log = common::nmea_dir().join("mt3339.log");
    let (want, _) = gps_serial::decode_file(&log).unwrap();
    let text = std::fs::read(&log).unwrap();
    let half = text.len() / 2;
    let cut = half + text[half..].iter().position(|&b| b == b'\n').unwrap() + 1;
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("gps0");

    let (mut m1, s1) = TTYPort::pair().unwrap();
    make_link(&link, &s1.name().unwrap());
    let h = gps_serial::spawn(SerialReader::new(settings(link.to_str().unwrap(), 115_200)));
    wait_for("first connection", Duration::from_secs(5), || {
        h.status().is_some_and(|s| s.state != GpsState::Connecting)
    });
    // First half, with line noise and an over-long line spliced in between sentences.
    let mut noisy = b"\x00\xff\xfegarbage".to_vec();
    noisy.extend_from_slice(&text[..cut]);
    noisy.extend_from_slice(b"$GPGGA,");
    noisy.extend(std::iter::repeat_n(b'7', 400));
    noisy.extend_from_slice(b"\r\n\x13\x11");
    m1.write_all(&noisy).unwrap();
    let first = collect(&h.fixes, want.len(), Duration::from_secs(3));
    assert!(!first.is_empty());
    assert_eq!(
        first[..],
        want[..first.len()],
        "first half equals the file decode"
    );
    let st = h.status().unwrap();
    assert_eq!(st.state, GpsState::Fix, "{st:?}");

    // Unplug: both ends go away, the pts node vanishes, the link dangles. The link is pointed at
    // a path that never exists first: left at the freed pts number, it could meet the pty that a
    // test running alongside opens next under that number.
    make_link(&link, &dir.path().join("unplugged").display().to_string());
    drop(m1);
    drop(s1);
    wait_for("reconnecting state", Duration::from_secs(5), || {
        h.status()
            .is_some_and(|s| s.state == GpsState::Reconnecting)
    });
    let st = h.status().unwrap();
    assert!(st.summary.starts_with("reconnecting to"), "{}", st.summary);
    assert_eq!(st.reconnects, 0);
    thread::sleep(Duration::from_millis(800)); // a few failed attempts with back-off

    // Plug back in: a new pty appears at the same link.
    let (mut m2, s2) = TTYPort::pair().unwrap();
    make_link(&link, &s2.name().unwrap());
    wait_for("reconnect", Duration::from_secs(5), || {
        h.status().is_some_and(|s| s.reconnects == 1)
    });
    m2.write_all(&text[cut..]).unwrap();
    let second = collect(&h.fixes, want.len() - first.len(), Duration::from_secs(3));
    let st = h.status().unwrap();
    h.stop();
    drop(s2);
    assert_eq!(st.reconnects, 1);
    assert_eq!(st.state, GpsState::Fix, "{st:?}");
    let mut all = first;
    all.extend(second);
    assert_eq!(all, want, "no fix lost or altered across the reconnect");
}

#[test]
fn silent_device_reports_no_data_then_no_fix() {
    if skip_under_qemu() {
        return;
    }
    let (mut m, s) = TTYPort::pair().unwrap();
    let mut r = SerialReader::new(settings(&s.name().unwrap(), 9600));
    let start = Instant::now();
    while !r.is_connected() && start.elapsed() < Duration::from_secs(5) {
        r.poll(|_| {});
    }
    assert!(r.is_connected());
    // Sentences without a fix (sl869's cold start): the status must say "no fix", not crash.
    m.write_all(b"$GPGGA,102136.000,3340.8472,S,15117.3205,E,0,02,99.0,064.19,M,22.4,M,,*41\r\n")
        .unwrap();
    let mut fixes = 0;
    for _ in 0..5 {
        r.poll(|_| fixes += 1);
    }
    let st = r.status();
    assert_eq!((fixes, st.state), (0, GpsState::NoFix), "{st:?}");
    assert!(st.summary.starts_with("no fix for"), "{}", st.summary);
    assert_eq!(st.decode.no_fix_sentences, 1);
    drop(s);
}
