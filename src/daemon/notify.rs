//! systemd integration without libsystemd: `sd_notify` datagrams and the watchdog interval.
//! (Log records reach journald through `tracing-journald`, installed by `super::logging`.)

use std::os::unix::net::UnixDatagram;
use std::time::Duration;

/// Send a state string (`READY=1`, `STATUS=…`, `WATCHDOG=1`, `STOPPING=1`) to the service
/// manager named by `$NOTIFY_SOCKET`. Returns `false` when not run by systemd (no variable) or the
/// send failed: notification is advisory and never stops the service.
pub(crate) fn notify(state: &str) -> bool {
    let Some(path) = std::env::var_os("NOTIFY_SOCKET") else {
        return false;
    };
    let Ok(sock) = UnixDatagram::unbound() else {
        return false;
    };
    // Never block the main loop (which feeds the watchdog) on a manager that reads slowly: a
    // notification that cannot be queued now is dropped, the next one carries the news.
    if sock.set_nonblocking(true).is_err() {
        return false;
    }
    let bytes = path.as_encoded_bytes();
    // An '@' prefix names a socket in the abstract namespace.
    if let Some(name) = bytes.strip_prefix(b"@") {
        use std::os::linux::net::SocketAddrExt;
        match std::os::unix::net::SocketAddr::from_abstract_name(name) {
            Ok(addr) => sock.send_to_addr(state.as_bytes(), &addr).is_ok(),
            Err(_) => false,
        }
    } else {
        sock.send_to(state.as_bytes(), &path).is_ok()
    }
}

/// The watchdog interval systemd asked for (`$WATCHDOG_USEC`, for this process per
/// `$WATCHDOG_PID`), if any.
pub(crate) fn watchdog_interval() -> Option<Duration> {
    if let Some(pid) = std::env::var_os("WATCHDOG_PID") {
        if pid.to_str()?.parse::<u32>().ok()? != std::process::id() {
            return None;
        }
    }
    let us: u64 = std::env::var("WATCHDOG_USEC").ok()?.parse().ok()?;
    (us > 0).then(|| Duration::from_micros(us))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn notify_reaches_a_path_socket() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("notify");
        let rx = UnixDatagram::bind(&p).unwrap();
        // Tests share the process environment; this is the only test that sets NOTIFY_SOCKET.
        std::env::set_var("NOTIFY_SOCKET", &p);
        assert!(notify("READY=1\nSTATUS=ok"));
        std::env::remove_var("NOTIFY_SOCKET");
        let mut buf = [0u8; 64];
        let n = rx.recv(&mut buf).unwrap();
        assert_eq!(&buf[..n], b"READY=1\nSTATUS=ok");
        assert!(!notify("READY=1"));
    }
}
