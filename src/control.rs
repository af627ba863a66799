//! The technician control socket (I/O shell): a Unix stream socket carrying length-prefixed JSON.
//!
//! Framing: each message is a 4-byte big-endian length followed by that many bytes. Requests are
//! one JSON object ([`Request`]) of at most [`MAX_REQUEST_BYTES`]; the server answers with zero or
//! more progress objects (`{"progress": …}`, relocalize with `wait`) and one final object that
//! always has `"ok"` (and `"error"` when not ok). `dump-overlay` follows its final object with one
//! raw frame of PNG bytes. The server reads with a timeout, serves at most
//! [`MAX_CONNECTIONS`] clients at once (more are told so and closed), and logs each client's
//! credentials (SO_PEERCRED). Access control is the file mode: 0660, owner and group of the
//! service, inside the service's 0750 runtime directory.

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use serde_json::{json, Value};
use std::io::{Read, Write};
use std::os::unix::fs::PermissionsExt;
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// Largest request the server reads; a longer length prefix closes the connection.
pub const MAX_REQUEST_BYTES: u32 = 64 * 1024;
/// Largest response frame a client accepts (an overlay PNG of a 5 MP frame is a few MB).
pub const MAX_RESPONSE_BYTES: u32 = 256 * 1024 * 1024;
/// Clients served at once; the next one gets a `busy` answer.
pub const MAX_CONNECTIONS: usize = 8;
/// How long the server waits for a request once a client connected.
pub const REQUEST_TIMEOUT: Duration = Duration::from_secs(5);
/// How long a write to a client may block (a stuck reader must not pin a server thread).
pub const WRITE_TIMEOUT: Duration = Duration::from_secs(30);
/// Mode of the socket file: the service's user and group (technicians are added to it).
pub const SOCKET_MODE: u32 = 0o660;

/// A request from a technician command.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "request", rename_all = "kebab-case", deny_unknown_fields)]
pub enum Request {
    /// The service's state, served pose, last run, schedules.
    // Struct variants (not unit) so that `deny_unknown_fields` also rejects stray keys here.
    Status {},
    /// The served pose file (contracts §4) as JSON.
    GetPose {},
    /// Localize now. With `wait`, progress is streamed and the final answer is the run's result;
    /// `force` serves the result even if its quality is below the served pose's.
    Relocalize {
        /// Stream progress and answer with the result.
        #[serde(default)]
        wait: bool,
        /// Serve an ok result even if it scores below the served pose.
        #[serde(default)]
        force: bool,
    },
    /// The LiDAR-over-image overlay of the latest run, as a PNG frame after the answer.
    DumpOverlay {},
    /// Validate the daemon's config file as a reload would read it.
    Validate {},
}

/// Write one frame.
pub fn write_frame(w: &mut impl Write, bytes: &[u8]) -> std::io::Result<()> {
    let n = u32::try_from(bytes.len()).map_err(|_| {
        std::io::Error::new(std::io::ErrorKind::InvalidInput, "frame larger than 4 GiB")
    })?;
    w.write_all(&n.to_be_bytes())?;
    w.write_all(bytes)?;
    w.flush()
}

/// Read one frame of at most `cap` bytes. `Ok(None)` on a clean end of stream before a frame.
pub fn read_frame(r: &mut impl Read, cap: u32) -> std::io::Result<Option<Vec<u8>>> {
    let mut len = [0u8; 4];
    match r.read_exact(&mut len) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(None),
        Err(e) => return Err(e),
    }
    let n = u32::from_be_bytes(len);
    if n > cap {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("frame of {n} bytes exceeds the {cap}-byte limit"),
        ));
    }
    let mut buf = vec![0u8; n as usize];
    r.read_exact(&mut buf)?;
    Ok(Some(buf))
}

/// Write one JSON value as a frame.
pub fn write_json(w: &mut impl Write, v: &Value) -> std::io::Result<()> {
    write_frame(w, v.to_string().as_bytes())
}

/// Who is on the other end of a Unix socket (SO_PEERCRED).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PeerCred {
    /// Process id.
    pub pid: i32,
    /// User id.
    pub uid: u32,
    /// Group id.
    pub gid: u32,
}

/// The peer's credentials, if the kernel tells them.
pub fn peer_cred(s: &UnixStream) -> Option<PeerCred> {
    use std::os::fd::AsRawFd;
    let mut cred = libc::ucred {
        pid: 0,
        uid: 0,
        gid: 0,
    };
    let mut len = std::mem::size_of::<libc::ucred>() as libc::socklen_t;
    // SAFETY: `cred` and `len` are valid for writes of the sizes given, and the fd is open for
    // the duration of the call (borrowed from `s`).
    let rc = unsafe {
        libc::getsockopt(
            s.as_raw_fd(),
            libc::SOL_SOCKET,
            libc::SO_PEERCRED,
            (&mut cred as *mut libc::ucred).cast(),
            &mut len,
        )
    };
    (rc == 0).then_some(PeerCred {
        pid: cred.pid,
        uid: cred.uid,
        gid: cred.gid,
    })
}

/// What a request handler can send besides its final answer.
pub trait Reply {
    /// Send a progress object (relocalize with `wait`).
    fn progress(&mut self, v: &Value) -> std::io::Result<()>;
}

/// The daemon's side: answers one request. The returned value is the final answer; an optional
/// byte payload follows it as one raw frame (the overlay PNG).
pub type Handler = dyn Fn(Request, &mut dyn Reply) -> (Value, Option<Vec<u8>>) + Send + Sync;

struct StreamReply<'a>(&'a mut UnixStream);

impl Reply for StreamReply<'_> {
    fn progress(&mut self, v: &Value) -> std::io::Result<()> {
        write_json(self.0, v)
    }
}

/// Bind the control socket: create its directory if missing (0750; under systemd the
/// RuntimeDirectory exists already), remove a stale socket left by a crash (only a socket, never
/// another kind of file), bind, and set [`SOCKET_MODE`].
pub fn bind(path: &Path) -> Result<UnixListener> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        if !dir.exists() {
            std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
            let _ = std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o750));
        }
    }
    if let Ok(meta) = std::fs::symlink_metadata(path) {
        use std::os::unix::fs::FileTypeExt;
        if !meta.file_type().is_socket() {
            return Err(Error::input(
                path,
                "control socket path exists and is not a socket; refusing to replace it",
            ));
        }
        // A live daemon still answering here means a second instance: refuse rather than steal.
        if UnixStream::connect(path).is_ok() {
            return Err(Error::input(
                path,
                "another infraloc daemon is listening on this control socket",
            ));
        }
        std::fs::remove_file(path).map_err(|e| Error::io(path, e))?;
    }
    let l = UnixListener::bind(path).map_err(|e| Error::io(path, e))?;
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(SOCKET_MODE))
        .map_err(|e| Error::io(path, e))?;
    Ok(l)
}

/// The server's limits.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    /// Clients served at once.
    pub max_connections: usize,
    /// How long to wait for a client's request.
    pub request_timeout: Duration,
}

impl Default for Limits {
    /// [`MAX_CONNECTIONS`], [`REQUEST_TIMEOUT`].
    fn default() -> Self {
        Limits {
            max_connections: MAX_CONNECTIONS,
            request_timeout: REQUEST_TIMEOUT,
        }
    }
}

/// Serve connections on `listener` until the process ends, one thread per client, at most
/// `limits.max_connections` at once. `log` receives one line per client and per protocol fault.
pub fn serve(
    listener: UnixListener,
    handler: Arc<Handler>,
    log: Arc<dyn Fn(&str) + Send + Sync>,
    limits: Limits,
) -> std::thread::JoinHandle<()> {
    let active = Arc::new(AtomicUsize::new(0));
    std::thread::Builder::new()
        .name("control".into())
        .spawn(move || {
            for conn in listener.incoming() {
                let mut stream = match conn {
                    Ok(s) => s,
                    Err(e) => {
                        log(&format!("control: accept failed: {e}"));
                        std::thread::sleep(Duration::from_millis(100));
                        continue;
                    }
                };
                let max = limits.max_connections;
                if active.fetch_add(1, Ordering::SeqCst) >= max {
                    active.fetch_sub(1, Ordering::SeqCst);
                    let _ = stream.set_write_timeout(Some(limits.request_timeout));
                    let _ = write_json(
                        &mut stream,
                        &json!({"ok": false, "error": format!("busy: {max} clients connected")}),
                    );
                    continue;
                }
                let (h, l, a) = (handler.clone(), log.clone(), active.clone());
                let spawned = std::thread::Builder::new()
                    .name("control-client".into())
                    .spawn(move || {
                        serve_one(&mut stream, h.as_ref(), l.as_ref(), limits.request_timeout);
                        a.fetch_sub(1, Ordering::SeqCst);
                    });
                if spawned.is_err() {
                    active.fetch_sub(1, Ordering::SeqCst);
                    log("control: cannot start a client thread");
                }
            }
        })
        .unwrap_or_else(|e| panic!("cannot start the control thread: {e}"))
}

fn serve_one(
    stream: &mut UnixStream,
    handler: &Handler,
    log: &(dyn Fn(&str) + Send + Sync),
    timeout: Duration,
) {
    let who = match peer_cred(stream) {
        Some(c) => format!("pid {} uid {} gid {}", c.pid, c.uid, c.gid),
        None => "unknown peer".into(),
    };
    let _ = stream.set_read_timeout(Some(timeout));
    let _ = stream.set_write_timeout(Some(WRITE_TIMEOUT));
    let req = match read_frame(stream, MAX_REQUEST_BYTES) {
        Ok(Some(b)) => serde_json::from_slice::<Request>(&b).map_err(|e| e.to_string()),
        Ok(None) => return,
        Err(e) => Err(e.to_string()),
    };
    let req = match req {
        Ok(r) => r,
        Err(e) => {
            log(&format!("control: bad request from {who}: {e}"));
            let _ = write_json(
                stream,
                &json!({"ok": false, "error": format!("bad request: {e}")}),
            );
            return;
        }
    };
    log(&format!("control: {req:?} from {who}"));
    let (answer, payload) = handler(req, &mut StreamReply(stream));
    if write_json(stream, &answer).is_ok() {
        if let Some(p) = payload {
            let _ = write_frame(stream, &p);
        }
    }
}

/// A technician command's connection to the daemon.
pub struct Client {
    stream: UnixStream,
    path: PathBuf,
}

impl Client {
    /// Connect; the error names the socket and hints at the service.
    pub fn connect(path: &Path) -> Result<Client> {
        let stream = UnixStream::connect(path).map_err(|e| {
            Error::input(
                path,
                format!("cannot reach the infraloc daemon ({e}); is infraloc.service running?"),
            )
        })?;
        Ok(Client {
            stream,
            path: path.to_path_buf(),
        })
    }

    /// Send `req`; call `on_progress` for each progress object; return the final answer and the
    /// payload frame, if the request has one. `timeout` bounds each wait for a frame.
    pub fn call(
        &mut self,
        req: &Request,
        timeout: Duration,
        mut on_progress: impl FnMut(&Value),
    ) -> Result<(Value, Option<Vec<u8>>)> {
        let io = |e: std::io::Error| Error::io(&self.path, e);
        self.stream.set_read_timeout(Some(timeout)).map_err(io)?;
        let text = serde_json::to_vec(req).map_err(|e| Error::Invalid(e.to_string()))?;
        write_frame(&mut self.stream, &text).map_err(io)?;
        loop {
            let frame = read_frame(&mut self.stream, MAX_RESPONSE_BYTES)
                .map_err(io)?
                .ok_or_else(|| Error::input(&self.path, "the daemon closed the connection"))?;
            let v: Value = serde_json::from_slice(&frame)
                .map_err(|e| Error::input(&self.path, format!("unreadable answer: {e}")))?;
            if v.get("progress").is_some() && v.get("ok").is_none() {
                on_progress(&v);
                continue;
            }
            let payload = if matches!(req, Request::DumpOverlay {}) && v["ok"] == json!(true) {
                read_frame(&mut self.stream, MAX_RESPONSE_BYTES).map_err(io)?
            } else {
                None
            };
            return Ok((v, payload));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requests_round_trip_and_reject_unknown_fields() {
        for r in [
            Request::Status {},
            Request::GetPose {},
            Request::Relocalize {
                wait: true,
                force: false,
            },
            Request::DumpOverlay {},
            Request::Validate {},
        ] {
            let s = serde_json::to_string(&r).unwrap();
            assert_eq!(serde_json::from_str::<Request>(&s).unwrap(), r, "{s}");
        }
        assert_eq!(
            serde_json::from_str::<Request>(r#"{"request":"relocalize"}"#).unwrap(),
            Request::Relocalize {
                wait: false,
                force: false
            }
        );
        assert!(serde_json::from_str::<Request>(r#"{"request":"status","x":1}"#).is_err());
        assert!(serde_json::from_str::<Request>(r#"{"request":"reboot"}"#).is_err());
    }

    #[test]
    fn frames_round_trip_and_enforce_the_cap() {
        let mut buf = Vec::new();
        write_frame(&mut buf, b"hello").unwrap();
        write_frame(&mut buf, b"").unwrap();
        let mut r = &buf[..];
        assert_eq!(read_frame(&mut r, 16).unwrap().unwrap(), b"hello");
        assert_eq!(read_frame(&mut r, 16).unwrap().unwrap(), b"");
        assert!(read_frame(&mut r, 16).unwrap().is_none());
        let mut big = Vec::new();
        write_frame(&mut big, &[0u8; 32]).unwrap();
        let e = read_frame(&mut &big[..], 16).unwrap_err();
        assert!(e.to_string().contains("exceeds the 16-byte limit"), "{e}");
        // A truncated frame is an error, not a short read.
        assert!(read_frame(&mut &big[..10], 64).is_err());
    }

    #[test]
    fn server_answers_limits_and_rejects_garbage() {
        let d = tempfile::tempdir().unwrap();
        let path = d.path().join("run/control.sock");
        let l = bind(&path).unwrap();
        let mode = std::fs::metadata(&path).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode, SOCKET_MODE);
        // A second bind while the first is live is refused.
        assert!(bind(&path)
            .unwrap_err()
            .to_string()
            .contains("another infraloc daemon"));
        // `Validate` blocks while `release` is set (holding its client's slot); `entered` counts
        // the handlers that started.
        let release = Arc::new(std::sync::atomic::AtomicBool::new(false));
        let entered = Arc::new(AtomicUsize::new(0));
        let (r2, e2) = (release.clone(), entered.clone());
        let handler: Arc<Handler> = Arc::new(move |req, reply: &mut dyn Reply| match req {
            Request::Validate {} => {
                e2.fetch_add(1, Ordering::SeqCst);
                let start = std::time::Instant::now();
                while r2.load(Ordering::SeqCst) && start.elapsed() < Duration::from_secs(60) {
                    std::thread::sleep(Duration::from_millis(10));
                }
                (json!({"ok": true}), None)
            }
            Request::Relocalize { .. } => {
                reply.progress(&json!({"progress": "capture"})).unwrap();
                (json!({"ok": true, "result": "done"}), None)
            }
            Request::DumpOverlay {} => (json!({"ok": true}), Some(vec![1, 2, 3])),
            _ => (json!({"ok": true, "state": "ok"}), None),
        });
        serve(l, handler, Arc::new(|_| {}), Limits::default());
        let mut c = Client::connect(&path).unwrap();
        let (v, _) = c
            .call(&Request::Status {}, Duration::from_secs(5), |_| {})
            .unwrap();
        assert_eq!(v["state"], "ok");
        let mut seen = Vec::new();
        let (v, _) = Client::connect(&path)
            .unwrap()
            .call(
                &Request::Relocalize {
                    wait: true,
                    force: false,
                },
                Duration::from_secs(5),
                |p| seen.push(p["progress"].clone()),
            )
            .unwrap();
        assert_eq!((v["result"].as_str(), seen.len()), (Some("done"), 1));
        let (_, png) = Client::connect(&path)
            .unwrap()
            .call(&Request::DumpOverlay {}, Duration::from_secs(5), |_| {})
            .unwrap();
        assert_eq!(png, Some(vec![1, 2, 3]));

        // Garbage and an over-long length prefix get an error answer or a closed connection.
        let mut s = UnixStream::connect(&path).unwrap();
        write_frame(&mut s, b"{not json").unwrap();
        let v: Value =
            serde_json::from_slice(&read_frame(&mut s, 1 << 20).unwrap().unwrap()).unwrap();
        assert_eq!(v["ok"], false);
        assert!(v["error"].as_str().unwrap().starts_with("bad request"));
        let mut s = UnixStream::connect(&path).unwrap();
        s.write_all(&(MAX_REQUEST_BYTES + 1).to_be_bytes()).unwrap();
        let v: Value =
            serde_json::from_slice(&read_frame(&mut s, 1 << 20).unwrap().unwrap()).unwrap();
        assert!(v["error"].as_str().unwrap().contains("limit"), "{v}");

        // Clients beyond the limit are turned away while the first ones hold their slot: each of
        // those sends a request whose handler blocks until released, so the slots are held
        // whatever the timing.
        release.store(true, Ordering::SeqCst);
        let held: Vec<_> = (0..MAX_CONNECTIONS)
            .map(|_| {
                let p = path.clone();
                std::thread::spawn(move || {
                    Client::connect(&p)
                        .unwrap()
                        .call(&Request::Validate {}, Duration::from_secs(60), |_| {})
                        .unwrap()
                })
            })
            .collect();
        let start = std::time::Instant::now();
        while entered.load(Ordering::SeqCst) < MAX_CONNECTIONS {
            assert!(
                start.elapsed() < Duration::from_secs(60),
                "clients never held their slots"
            );
            std::thread::sleep(Duration::from_millis(10));
        }
        let mut extra = UnixStream::connect(&path).unwrap();
        let v: Value =
            serde_json::from_slice(&read_frame(&mut extra, 1 << 20).unwrap().unwrap()).unwrap();
        assert!(v["error"].as_str().unwrap().starts_with("busy"), "{v}");
        release.store(false, Ordering::SeqCst);
        for h in held {
            assert_eq!(h.join().unwrap().0["ok"], true);
        }
    }
}
