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
use crate::stage::StageName;
use serde::de::{DeserializeOwned, IgnoredAny};
use serde::{Deserialize, Serialize};
use std::io::{Read, Write};
use std::os::unix::fs::PermissionsExt;
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Largest request the server reads; a longer length prefix closes the connection. Sized for a
/// `georef` batch of [`MAX_GEOREF_PIXELS`] pixels written with full f64 precision (about 40
/// bytes a pixel, 400 kB), with room to spare.
pub const MAX_REQUEST_BYTES: u32 = 1024 * 1024;
/// Most pixels one `georef` request may carry. A detector's frame has tens to hundreds of
/// ground-contact points; 10 000 is a whole frame's worth of dense keypoints, answered in about
/// 10 ms of one core and a 4 MB answer, so one client cannot hold a slot or the pose lock for
/// long, and a larger job is split or uses the lookup table.
pub const MAX_GEOREF_PIXELS: usize = 10_000;
/// Largest response frame a client accepts (an overlay PNG of a 5 MP frame is a few MB).
pub(crate) const MAX_RESPONSE_BYTES: u32 = 256 * 1024 * 1024;
/// Clients served at once; the next one gets a `busy` answer.
pub const MAX_CONNECTIONS: usize = 8;
/// How long a client may take to send its whole request once connected.
pub(crate) const REQUEST_TIMEOUT: Duration = Duration::from_secs(5);
/// How long a write to a client may block (a stuck reader must not pin a server thread).
pub(crate) const WRITE_TIMEOUT: Duration = Duration::from_secs(30);
/// Mode of the socket file: the service's user and group (technicians are added to it).
pub(crate) const SOCKET_MODE: u32 = 0o660;

/// A request from a technician command.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "request", rename_all = "kebab-case", deny_unknown_fields)]
pub enum Request {
    /// The service's state, served pose, last run, schedules.
    // Struct variants (not unit) so that `deny_unknown_fields` also rejects stray keys here.
    Status {},
    /// The served pose file (docs/interfaces.md, "Pose file") as JSON.
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
    /// Drop the frames of earlier runs that later runs would pool (the camera was moved, or
    /// its frames are not to be trusted): `{"ok": true, "cleared": N}`.
    ClearFrames {},
    /// Validate the daemon's config file as a reload would read it.
    Validate {},
    /// Georeference pixels through the served pose on the tile's height layer
    /// (docs/georef.md "The service's `georef` request"): at most [`MAX_GEOREF_PIXELS`].
    Georef {
        /// Pixels (u, v), OpenCV convention; JSON has no NaN, so a non-finite coordinate is
        /// `null` (the pixel gets the status `non_finite`).
        pixels: Vec<[Option<f64>; 2]>,
        /// Pixel noise σ (px) added to each point's covariance.
        #[serde(default)]
        sigma_px: f64,
        /// σ of the height layer (m) carried along each ray; absent: the layer's own estimate.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        height_sigma_m: Option<f64>,
    },
}

impl Request {
    /// Requests answered from what the service holds, at once and without changing anything:
    /// they are also served by an overflow reader when every slot is taken.
    pub fn is_quick_read(&self) -> bool {
        matches!(self, Request::Status {} | Request::Georef { .. })
    }

    /// The request as the log names it: its `Debug` form, except that a `georef` batch is
    /// counted rather than listed.
    pub fn name(&self) -> String {
        match self {
            Request::Georef {
                pixels,
                sigma_px,
                height_sigma_m,
            } => {
                format!(
                    "Georef {{ {} pixels, sigma_px: {sigma_px}, height_sigma_m: {height_sigma_m:?} }}",
                    pixels.len()
                )
            }
            r => format!("{r:?}"),
        }
    }
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

/// Write one message as a JSON frame. The object's keys are sorted (through `serde_json::Value`,
/// whose maps are ordered), so a typed answer reads on the wire exactly as the same answer built
/// as a JSON object.
pub(crate) fn write_json(w: &mut impl Write, v: &impl Serialize) -> std::io::Result<()> {
    let v = serde_json::to_value(v).map_err(std::io::Error::other)?;
    write_frame(w, v.to_string().as_bytes())
}

/// A progress message, sent before the final answer of `relocalize` with `wait`:
/// `{"progress": STAGE}`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Progress {
    /// The stage that started.
    pub progress: StageName,
}

/// A final answer that serves the request: `"ok": true` with the fields of `T` beside it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) struct Accepted<T> {
    ok: bool,
    /// The request's own fields.
    #[serde(flatten)]
    pub body: T,
}

impl<T> Accepted<T> {
    /// The answer serving `body`.
    pub(crate) fn new(body: T) -> Self {
        Accepted { ok: true, body }
    }
}

/// A final answer that does not serve the request: `{"ok": false, "error": WHY}`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub(crate) struct Refusal {
    ok: bool,
    /// Why, one line.
    pub error: String,
}

impl Refusal {
    /// The refusal for `error`.
    pub(crate) fn new(error: impl Into<String>) -> Self {
        Refusal {
            ok: false,
            error: error.into(),
        }
    }
}

/// What every final answer carries, whatever the request: whether it was served, and why not.
#[derive(Deserialize)]
struct Head {
    ok: bool,
    #[serde(default)]
    error: Option<String>,
}

/// Enough of a frame to tell a progress message (`progress` without `ok`) from a final answer.
#[derive(Deserialize)]
struct Peek {
    #[serde(default)]
    ok: Option<IgnoredAny>,
    #[serde(default)]
    progress: Option<IgnoredAny>,
}

/// Who is on the other end of a Unix socket (SO_PEERCRED).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct PeerCred {
    /// Process id.
    pub pid: i32,
    /// User id.
    pub uid: u32,
    /// Group id.
    pub gid: u32,
}

/// The peer's credentials, if the kernel tells them.
pub(crate) fn peer_cred(s: &UnixStream) -> Option<PeerCred> {
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
    /// Send a progress message (relocalize with `wait`).
    fn progress(&mut self, p: Progress) -> std::io::Result<()>;
}

/// The daemon's side: answers one request. The returned `A` is the final answer (an object with
/// `"ok"`, see `Accepted` and `Refusal`); an optional byte payload follows it as one raw
/// frame (the overlay PNG).
pub type Handler<A> = dyn Fn(Request, &mut dyn Reply) -> (A, Option<Vec<u8>>) + Send + Sync;

struct StreamReply<'a>(&'a mut UnixStream);

impl Reply for StreamReply<'_> {
    fn progress(&mut self, p: Progress) -> std::io::Result<()> {
        write_json(self.0, &p)
    }
}

/// Mode of the socket's directory: the service's user (rwx) and group (r-x), nobody else.
pub(crate) const DIR_MODE: u32 = 0o750;

/// Bind the control socket: create its directory if missing (`DIR_MODE`; under systemd the
/// RuntimeDirectory exists already), tighten an existing directory of ours that grants more than
/// `DIR_MODE` (refuse one of another user's), remove a stale socket left by a crash (only a
/// socket, never another kind of file), bind, and set `SOCKET_MODE`. Returns the listener and
/// a note for the log when the directory's mode was changed.
pub fn bind(path: &Path) -> Result<(UnixListener, Option<String>)> {
    let mut note = None;
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        if !dir.exists() {
            std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
            std::fs::set_permissions(dir, std::fs::Permissions::from_mode(DIR_MODE))
                .map_err(|e| Error::io(dir, e))?;
        } else {
            note = secure_dir(dir, path)?;
        }
    }
    if let Ok(meta) = std::fs::symlink_metadata(path) {
        use std::os::unix::fs::FileTypeExt;
        if !meta.file_type().is_socket() {
            return Err(Error::input(
                path,
                "the path exists and is not a socket; refusing to replace it",
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
    Ok((l, note))
}

/// An existing socket directory should grant no more than [`DIR_MODE`]: others must not reach
/// the socket, and nobody but the service may replace it. A directory of the service's own that
/// holds nothing but the socket (a runtime directory whose mode was loosened) is tightened to
/// it, and the note says so. Any other directory (another user's, a shared sticky one like /tmp,
/// one with other files like /run or a scene directory) is not changed, since that would affect
/// others: refused with the reason if group or others may write it (they could replace the
/// socket), accepted with a note if they may only look in (the socket's 0660 keeps them out).
fn secure_dir(dir: &Path, socket: &Path) -> Result<Option<String>> {
    use std::os::unix::fs::MetadataExt;
    let m = std::fs::metadata(dir).map_err(|e| Error::io(dir, e))?;
    if !m.is_dir() {
        return Err(Error::input(
            dir,
            "the socket's directory is not a directory",
        ));
    }
    let mode = m.mode() & 0o7777;
    if mode & !DIR_MODE == 0 {
        return Ok(None);
    }
    // SAFETY: geteuid has no preconditions and cannot fail.
    let me = unsafe { libc::geteuid() };
    let others = std::fs::read_dir(dir)
        .map_err(|e| Error::io(dir, e))?
        .filter_map(|e| e.ok())
        .any(|e| Some(e.file_name().as_os_str()) != socket.file_name());
    let why_not = if m.uid() != me {
        Some(format!(
            "it belongs to uid {}, not this service's uid {me}",
            m.uid()
        ))
    } else if mode & 0o1000 != 0 {
        Some("it is a shared (sticky) directory".to_string())
    } else if others {
        Some("it holds other files".to_string())
    } else {
        None
    };
    if let Some(w) = why_not {
        if mode & 0o022 == 0 {
            // Others may only look in (0755, like /run or a scene directory): the socket's own
            // mode (0660) keeps them out, and changing a shared directory would affect others.
            return Ok(Some(format!(
                "control socket directory {} has mode {mode:04o} (not tightened: {w}); the socket's mode {SOCKET_MODE:04o} keeps others out",
                dir.display()
            )));
        }
        return Err(Error::input(
            dir,
            format!(
                "the socket's directory has mode {mode:04o}: others could replace the socket, and {w}, so it is not tightened; give the socket a directory of its own with mode 0750 (systemd's RuntimeDirectory)"
            ),
        ));
    }
    let tight = mode & DIR_MODE;
    std::fs::set_permissions(dir, std::fs::Permissions::from_mode(tight))
        .map_err(|e| Error::io(dir, e))?;
    Ok(Some(format!(
        "control socket directory {}: mode {mode:04o} tightened to {tight:04o}",
        dir.display()
    )))
}

/// The server's limits.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    /// Clients served at once.
    pub max_connections: usize,
    /// How long a client may take to send its whole request (a deadline, not a per-read timeout:
    /// a client trickling one byte at a time is cut off all the same).
    pub request_timeout: Duration,
    /// A client that has not sent a whole request for this long is closed to make room for a
    /// new one when every slot is taken (technician commands send theirs at once).
    pub evict_idle_after: Duration,
    /// Clients read at once beyond `max_connections` when nothing can be evicted: `status` is
    /// answered there, anything else is told `busy`.
    pub overflow_readers: usize,
    /// How long such a client may take to send its request.
    pub overflow_timeout: Duration,
}

impl Default for Limits {
    /// [`MAX_CONNECTIONS`], `REQUEST_TIMEOUT`, idle eviction after 250 ms, 4 overflow readers
    /// with a 1 s deadline.
    fn default() -> Self {
        Limits {
            max_connections: MAX_CONNECTIONS,
            request_timeout: REQUEST_TIMEOUT,
            evict_idle_after: Duration::from_millis(250),
            overflow_readers: 4,
            overflow_timeout: Duration::from_secs(1),
        }
    }
}

/// A [`Read`] over a stream that fails with `TimedOut` once `deadline` has passed, however the
/// bytes trickle in.
struct DeadlineReader<'a> {
    stream: &'a UnixStream,
    deadline: Instant,
}

impl Read for DeadlineReader<'_> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let left = self.deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Err(std::io::Error::new(
                std::io::ErrorKind::TimedOut,
                "the request was not complete in time",
            ));
        }
        self.stream.set_read_timeout(Some(left))?;
        let mut s = self.stream;
        match s.read(buf) {
            Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock) => {
                Err(std::io::Error::new(
                    std::io::ErrorKind::TimedOut,
                    "the request was not complete in time",
                ))
            }
            r => r,
        }
    }
}

/// Read one request frame, all of it before `timeout` from now.
fn read_request(stream: &UnixStream, timeout: Duration) -> std::io::Result<Option<Vec<u8>>> {
    let mut r = DeadlineReader {
        stream,
        deadline: Instant::now() + timeout,
    };
    read_frame(&mut r, MAX_REQUEST_BYTES)
}

/// One connection holding a slot.
struct Conn {
    id: u64,
    since: Instant,
    /// Still waiting for its request (evictable once idle long enough).
    reading: bool,
    /// A handle to close it on eviction.
    stream: UnixStream,
}

#[derive(Default)]
struct Table {
    next_id: u64,
    conns: Vec<Conn>,
    overflow: usize,
}

/// The server's connection slots. Each admitted client holds a [`SlotGuard`] that gives the
/// slot back when dropped, so a client thread that ends in any way (a panicking handler
/// included) cannot leak it.
#[derive(Default)]
struct Slots(Mutex<Table>);

/// How a new connection is admitted.
enum Admit {
    /// A slot of its own (maybe after evicting an idle client, whose description is given).
    Slot(SlotGuard, Option<String>),
    /// An overflow reader: `status` only.
    Overflow(OverflowGuard),
    /// Nothing left: answer busy at once.
    Busy,
}

/// Gives back a connection slot when dropped.
struct SlotGuard {
    slots: Arc<Slots>,
    id: u64,
}

impl SlotGuard {
    /// The request has been read: the client is no longer idle.
    fn serving(&self) {
        let mut t = lock(&self.slots.0);
        if let Some(c) = t.conns.iter_mut().find(|c| c.id == self.id) {
            c.reading = false;
        }
    }
}

impl Drop for SlotGuard {
    fn drop(&mut self) {
        lock(&self.slots.0).conns.retain(|c| c.id != self.id);
    }
}

/// Gives back an overflow reader when dropped.
struct OverflowGuard(Arc<Slots>);

impl Drop for OverflowGuard {
    fn drop(&mut self) {
        let mut t = lock(&self.0 .0);
        t.overflow = t.overflow.saturating_sub(1);
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    // The table stays consistent under every operation, so a poisoned lock is still usable.
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl Slots {
    fn admit(self: &Arc<Self>, stream: &UnixStream, limits: &Limits) -> Admit {
        let mut t = lock(&self.0);
        let mut evicted = None;
        if t.conns.len() >= limits.max_connections {
            let oldest_idle = t
                .conns
                .iter()
                .enumerate()
                .filter(|(_, c)| c.reading && c.since.elapsed() >= limits.evict_idle_after)
                .min_by_key(|(_, c)| c.since)
                .map(|(i, _)| i);
            match oldest_idle {
                Some(i) => {
                    let c = t.conns.remove(i);
                    let idle = c.since.elapsed().as_secs_f64();
                    let _ = c.stream.set_write_timeout(Some(Duration::from_millis(100)));
                    let _ = write_json(
                        &mut &c.stream,
                        &Refusal::new(format!("closed: no complete request after {idle:.1} s while every slot was taken")),
                    );
                    let _ = c.stream.shutdown(std::net::Shutdown::Both);
                    evicted = Some(format!("an idle client (no request for {idle:.1} s)"));
                }
                None if t.overflow < limits.overflow_readers => {
                    t.overflow += 1;
                    return Admit::Overflow(OverflowGuard(self.clone()));
                }
                None => return Admit::Busy,
            }
        }
        let Ok(handle) = stream.try_clone() else {
            return Admit::Busy;
        };
        let id = t.next_id;
        t.next_id += 1;
        t.conns.push(Conn {
            id,
            since: Instant::now(),
            reading: true,
            stream: handle,
        });
        Admit::Slot(
            SlotGuard {
                slots: self.clone(),
                id,
            },
            evicted,
        )
    }
}

/// The busy answer.
fn busy(max: usize) -> Refusal {
    Refusal::new(format!(
        "busy: {max} clients connected; try again in a few seconds"
    ))
}

/// Answer busy to a client no thread could be spared for: write the reason, close our write side
/// and drain what the client already sent, so that it reads the reason rather than a reset or a
/// broken pipe (the client also reads the answer when its own write fails).
fn refuse(stream: &mut UnixStream, max: usize) {
    let _ = stream.set_write_timeout(Some(Duration::from_millis(200)));
    let _ = write_json(stream, &busy(max));
    let _ = stream.shutdown(std::net::Shutdown::Write);
    if stream.set_nonblocking(true).is_ok() {
        let mut buf = [0u8; 4096];
        let mut left = MAX_REQUEST_BYTES as usize + 4;
        while left > 0 {
            match stream.read(&mut buf) {
                Ok(0) | Err(_) => break,
                Ok(n) => left = left.saturating_sub(n),
            }
        }
    }
}

/// Serve connections on `listener` until the process ends, one thread per client, at most
/// `limits.max_connections` at once; beyond that an idle client is evicted, or the newcomer is
/// read by an overflow reader that answers `status` and tells everything else `busy`. One
/// `tracing` record (INFO) per client and per protocol fault. A panicking handler answers an
/// internal error and gives its slot back.
pub fn serve<A: Serialize + 'static>(
    listener: UnixListener,
    handler: Arc<Handler<A>>,
    limits: Limits,
) -> std::thread::JoinHandle<()> {
    let slots = Arc::new(Slots::default());
    std::thread::Builder::new()
        .name("control".into())
        .spawn(move || {
            for conn in listener.incoming() {
                let mut stream = match conn {
                    Ok(s) => s,
                    Err(e) => {
                        tracing::info!("control: accept failed: {e}");
                        std::thread::sleep(Duration::from_millis(100));
                        continue;
                    }
                };
                let max = limits.max_connections;
                let h = handler.clone();
                let spawned = match slots.admit(&stream, &limits) {
                    Admit::Slot(guard, evicted) => {
                        if let Some(e) = evicted {
                            tracing::info!("control: every slot taken; closed {e}");
                        }
                        std::thread::Builder::new()
                            .name("control-client".into())
                            .spawn(move || {
                                let _guard = &guard;
                                serve_one(&mut stream, h.as_ref(), &limits, || guard.serving());
                            })
                    }
                    Admit::Overflow(guard) => std::thread::Builder::new()
                        .name("control-overflow".into())
                        .spawn(move || {
                            let _guard = guard;
                            serve_overflow(&mut stream, h.as_ref(), &limits);
                        }),
                    Admit::Busy => {
                        refuse(&mut stream, max);
                        continue;
                    }
                };
                if spawned.is_err() {
                    tracing::info!("control: cannot start a client thread");
                }
            }
        })
        .unwrap_or_else(|e| panic!("cannot start the control thread: {e}"))
}

fn peer(stream: &UnixStream) -> String {
    match peer_cred(stream) {
        Some(c) => format!("pid {} uid {} gid {}", c.pid, c.uid, c.gid),
        None => "unknown peer".into(),
    }
}

/// Call the handler; a panic becomes a refusal (the slot is given back by its guard).
fn handle<A>(
    handler: &Handler<A>,
    req: Request,
    reply: &mut dyn Reply,
) -> std::result::Result<(A, Option<Vec<u8>>), Refusal> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| handler(req, reply))).map_err(|p| {
        let what = p
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| p.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "panic".into());
        Refusal::new(format!("internal error: {what}"))
    })
}

fn serve_one<A: Serialize>(
    stream: &mut UnixStream,
    handler: &Handler<A>,
    limits: &Limits,
    serving: impl FnOnce(),
) {
    let who = peer(stream);
    let _ = stream.set_write_timeout(Some(WRITE_TIMEOUT));
    let req = match read_request(stream, limits.request_timeout) {
        Ok(Some(b)) => serde_json::from_slice::<Request>(&b).map_err(|e| e.to_string()),
        Ok(None) => return,
        Err(e) => Err(e.to_string()),
    };
    serving();
    let req = match req {
        Ok(r) => r,
        Err(e) => {
            tracing::info!("control: bad request from {who}: {e}");
            let _ = write_json(stream, &Refusal::new(format!("bad request: {e}")));
            return;
        }
    };
    tracing::info!("control: {} from {who}", req.name());
    match handle(handler, req, &mut StreamReply(stream)) {
        Ok((answer, payload)) => {
            if write_json(stream, &answer).is_ok() {
                if let Some(p) = payload {
                    let _ = write_frame(stream, &p);
                }
            }
        }
        Err(refusal) => {
            let _ = write_json(stream, &refusal);
        }
    }
}

/// A client beyond the limit: read its request (so that our answer, not a broken pipe, reaches
/// it), answer `status`, tell anything else `busy`.
fn serve_overflow<A: Serialize>(stream: &mut UnixStream, handler: &Handler<A>, limits: &Limits) {
    let _ = stream.set_write_timeout(Some(limits.overflow_timeout));
    let req = read_request(stream, limits.overflow_timeout);
    let refusal = match req {
        Ok(Some(b)) => match serde_json::from_slice::<Request>(&b) {
            Ok(req) if req.is_quick_read() => {
                tracing::info!(
                    "control: {} from {} (every slot taken: answered on the overflow reader)",
                    req.name(),
                    peer(stream)
                );
                let mut sink = NoProgress;
                match handle(handler, req, &mut sink) {
                    Ok((answer, _)) => {
                        let _ = write_json(stream, &answer);
                        return;
                    }
                    Err(r) => r,
                }
            }
            Ok(_) => busy(limits.max_connections),
            Err(e) => Refusal::new(format!("bad request: {e}")),
        },
        Ok(None) => return,
        Err(_) => busy(limits.max_connections),
    };
    let _ = write_json(stream, &refusal);
}

/// Progress is not streamed to overflow clients (status has none).
struct NoProgress;

impl Reply for NoProgress {
    fn progress(&mut self, _: Progress) -> std::io::Result<()> {
        Ok(())
    }
}

/// A final answer as the client received it: the JSON text, and the payload frame that follows
/// `dump-overlay`'s.
#[derive(Debug, Clone)]
pub struct Answer {
    text: String,
    refused: Option<String>,
    payload: Option<Vec<u8>>,
    origin: PathBuf,
}

impl Answer {
    /// Check the part every answer has (`"ok"`, and `"error"` when not ok); an answer without
    /// it is an error naming what is missing.
    fn read(frame: Vec<u8>, origin: &Path) -> Result<Answer> {
        let unreadable = |e: String| Error::input(origin, format!("unreadable answer: {e}"));
        let head: Head = serde_json::from_slice(&frame).map_err(|e| unreadable(e.to_string()))?;
        let refused = match (head.ok, head.error) {
            (true, _) => None,
            (false, Some(e)) => Some(e),
            (false, None) => return Err(unreadable("\"ok\": false without \"error\"".into())),
        };
        let text = String::from_utf8(frame).map_err(|e| unreadable(e.to_string()))?;
        Ok(Answer {
            text,
            refused,
            payload: None,
            origin: origin.to_path_buf(),
        })
    }

    /// The JSON text as the daemon sent it.
    pub fn text(&self) -> &str {
        &self.text
    }

    /// Why the daemon did not serve the request (its `"error"`), or `None` when it did.
    pub fn refusal(&self) -> Option<&str> {
        self.refused.as_deref()
    }

    /// The answer's fields as `T`; `what` names the answer in the error, which says which field
    /// is missing or malformed.
    pub fn parse<T: DeserializeOwned>(&self, what: &str) -> Result<T> {
        serde_json::from_str(&self.text).map_err(|e| {
            Error::input(
                &self.origin,
                format!("the daemon's {what} does not parse: {e}"),
            )
        })
    }

    /// The payload frame that followed the answer, if any.
    pub(crate) fn payload(&self) -> Option<&[u8]> {
        self.payload.as_deref()
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

    /// Send `req`; call `on_progress` for each progress message (with the stage, or the message
    /// as it came when the stage is one this client does not know); return the final answer
    /// with the payload frame, if the request has one. `timeout` bounds each wait for a frame.
    pub fn call(
        &mut self,
        req: &Request,
        timeout: Duration,
        mut on_progress: impl FnMut(std::result::Result<StageName, &str>),
    ) -> Result<Answer> {
        let io = |e: std::io::Error| Error::io(&self.path, e);
        self.stream.set_read_timeout(Some(timeout)).map_err(io)?;
        let text = serde_json::to_vec(req).map_err(|e| Error::Encode(e.into()))?;
        if let Err(e) = write_frame(&mut self.stream, &text) {
            // A server that turned us away (busy) may have closed before reading our request:
            // its reason is waiting in our receive buffer, and it is what the technician needs.
            return match read_frame(&mut self.stream, MAX_RESPONSE_BYTES) {
                Ok(Some(frame)) => Answer::read(frame, &self.path).map_err(|_| io(e)),
                _ => Err(io(e)),
            };
        }
        loop {
            let frame = read_frame(&mut self.stream, MAX_RESPONSE_BYTES)
                .map_err(io)?
                .ok_or_else(|| Error::input(&self.path, "the daemon closed the connection"))?;
            let peek: Peek = serde_json::from_slice(&frame)
                .map_err(|e| Error::input(&self.path, format!("unreadable answer: {e}")))?;
            if peek.progress.is_some() && peek.ok.is_none() {
                match serde_json::from_slice::<Progress>(&frame) {
                    Ok(p) => on_progress(Ok(p.progress)),
                    Err(_) => on_progress(Err(&String::from_utf8_lossy(&frame))),
                }
                continue;
            }
            let mut answer = Answer::read(frame, &self.path)?;
            if matches!(req, Request::DumpOverlay {}) && answer.refusal().is_none() {
                answer.payload = read_frame(&mut self.stream, MAX_RESPONSE_BYTES).map_err(io)?;
            }
            return Ok(answer);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::{json, Value};
    use std::sync::atomic::{AtomicUsize, Ordering};

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
            Request::Georef {
                pixels: vec![[Some(1.5), None]],
                sigma_px: 0.5,
                height_sigma_m: Some(0.02),
            },
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
        // A georef batch: null is a non-finite coordinate; a string is not a pixel.
        assert_eq!(
            serde_json::from_str::<Request>(r#"{"request":"georef","pixels":[[1,null]]}"#).unwrap(),
            Request::Georef {
                pixels: vec![[Some(1.0), None]],
                sigma_px: 0.0,
                height_sigma_m: None,
            }
        );
        assert!(
            serde_json::from_str::<Request>(r#"{"request":"georef","pixels":[["a",1]]}"#).is_err()
        );
        assert!(serde_json::from_str::<Request>(r#"{"request":"georef","pixels":[[1]]}"#).is_err());
        let big = Request::Georef {
            pixels: vec![
                [Some(1_234.567_890_123_456_7), Some(-987.654_321_098_765_4)];
                MAX_GEOREF_PIXELS
            ],
            sigma_px: 0.0,
            height_sigma_m: Some(0.123_456_789),
        };
        assert!(serde_json::to_vec(&big).unwrap().len() < MAX_REQUEST_BYTES as usize);
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
    fn a_panicking_client_thread_gives_its_slot_back() {
        let (a, _b) = UnixStream::pair().unwrap();
        let slots = Arc::new(Slots::default());
        let limits = Limits {
            max_connections: 1,
            overflow_readers: 0,
            ..Limits::default()
        };
        for _ in 0..3 {
            let Admit::Slot(guard, _) = slots.admit(&a, &limits) else {
                panic!("the only slot was not free: leaked by the previous thread");
            };
            guard.serving();
            // The thread dies holding the guard, as a client thread whose handler panicked
            // outside catch_unwind would.
            let r = std::thread::spawn(move || {
                let _g = guard;
                panic!("handler bug");
            })
            .join();
            assert!(r.is_err());
        }
        assert!(lock(&slots.0).conns.is_empty());
        // With the slot held (and serving, so not evictable), the next one is busy.
        let Admit::Slot(held, _) = slots.admit(&a, &limits) else {
            panic!("slot not free");
        };
        held.serving();
        assert!(matches!(slots.admit(&a, &limits), Admit::Busy));
    }

    #[test]
    fn loose_socket_directory_of_ours_is_tightened() {
        let d = tempfile::tempdir().unwrap();
        let run = d.path().join("run");
        std::fs::create_dir(&run).unwrap();
        std::fs::set_permissions(&run, std::fs::Permissions::from_mode(0o777)).unwrap();
        let (_l, note) = bind(&run.join("c.sock")).unwrap();
        assert!(note.unwrap().contains("0777 tightened to 0750"));
        let mode = std::fs::metadata(&run).unwrap().permissions().mode() & 0o7777;
        assert_eq!(mode, 0o750);
    }

    #[test]
    fn loose_shared_socket_directory_is_refused_not_changed() {
        let d = tempfile::tempdir().unwrap();
        let run = d.path().join("run");
        std::fs::create_dir(&run).unwrap();
        std::fs::write(run.join("other"), "").unwrap();
        std::fs::set_permissions(&run, std::fs::Permissions::from_mode(0o775)).unwrap();
        let e = bind(&run.join("c.sock")).unwrap_err().to_string();
        assert!(
            e.contains("mode 0775") && e.contains("holds other files"),
            "{e}"
        );
        let mode = std::fs::metadata(&run).unwrap().permissions().mode() & 0o7777;
        assert_eq!(mode, 0o775);
    }

    #[test]
    fn server_answers_limits_and_rejects_garbage() {
        let d = tempfile::tempdir().unwrap();
        let path = d.path().join("run/control.sock");
        let (l, note) = bind(&path).unwrap();
        assert_eq!(note, None);
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
        let handler: Arc<Handler<Value>> = Arc::new(move |req, reply: &mut dyn Reply| match req {
            Request::Validate {} => {
                e2.fetch_add(1, Ordering::SeqCst);
                let start = std::time::Instant::now();
                while r2.load(Ordering::SeqCst) && start.elapsed() < Duration::from_secs(60) {
                    std::thread::sleep(Duration::from_millis(10));
                }
                (json!({"ok": true}), None)
            }
            Request::Relocalize { .. } => {
                reply
                    .progress(Progress {
                        progress: StageName::Capture,
                    })
                    .unwrap();
                (json!({"ok": true, "result": "done"}), None)
            }
            Request::DumpOverlay {} => (json!({"ok": true}), Some(vec![1, 2, 3])),
            _ => (json!({"ok": true, "state": "ok"}), None),
        });
        serve(l, handler, Limits::default());
        let mut c = Client::connect(&path).unwrap();
        let v: Value = c
            .call(&Request::Status {}, Duration::from_secs(5), |_| {})
            .unwrap()
            .parse("status")
            .unwrap();
        assert_eq!(v["state"], "ok");
        let mut seen = Vec::new();
        let v: Value = Client::connect(&path)
            .unwrap()
            .call(
                &Request::Relocalize {
                    wait: true,
                    force: false,
                },
                Duration::from_secs(5),
                |p| seen.push(p.ok()),
            )
            .unwrap()
            .parse("result")
            .unwrap();
        assert_eq!(
            (v["result"].as_str(), &seen[..]),
            (Some("done"), &[Some(StageName::Capture)][..])
        );
        let a = Client::connect(&path)
            .unwrap()
            .call(&Request::DumpOverlay {}, Duration::from_secs(5), |_| {})
            .unwrap();
        assert_eq!(a.payload(), Some(&[1u8, 2, 3][..]));

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
                std::thread::spawn(move || loop {
                    // A client thread of the requests above may not have given its slot back
                    // yet (a loaded machine): busy is then retried, as the technician commands do.
                    let a = Client::connect(&p)
                        .unwrap()
                        .call(&Request::Validate {}, Duration::from_secs(60), |_| {})
                        .unwrap();
                    if !a.refusal().is_some_and(|e| e.starts_with("busy")) {
                        break a;
                    }
                    std::thread::sleep(Duration::from_millis(20));
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
            assert_eq!(h.join().unwrap().refusal(), None);
        }
    }

    #[test]
    fn answers_read_as_they_always_did_on_the_wire() {
        // Typed answers carry the same sorted keys as the JSON objects they replace.
        let mut buf = Vec::new();
        write_json(&mut buf, &Refusal::new("busy: 8 clients")).unwrap();
        #[derive(Serialize)]
        struct Body {
            zeta: u8,
            alpha: &'static str,
        }
        write_json(
            &mut buf,
            &Accepted::new(Body {
                zeta: 1,
                alpha: "a",
            }),
        )
        .unwrap();
        let mut r = &buf[..];
        let frame = |r: &mut &[u8]| String::from_utf8(read_frame(r, 1 << 10).unwrap().unwrap());
        assert_eq!(
            frame(&mut r).unwrap(),
            r#"{"error":"busy: 8 clients","ok":false}"#
        );
        assert_eq!(
            frame(&mut r).unwrap(),
            r#"{"alpha":"a","ok":true,"zeta":1}"#
        );
    }

    #[test]
    fn an_answer_without_its_head_is_a_one_line_error() {
        let p = Path::new("c.sock");
        let e = Answer::read(br#"{"state":"ok"}"#.to_vec(), p).unwrap_err();
        assert_eq!(
            e.to_string(),
            "c.sock: unreadable answer: missing field `ok` at line 1 column 14"
        );
        let e = Answer::read(br#"{"ok":false}"#.to_vec(), p).unwrap_err();
        assert!(
            e.to_string().contains(r#""ok": false without "error""#),
            "{e}"
        );
        let a = Answer::read(br#"{"ok":false,"error":"no pose served yet"}"#.to_vec(), p).unwrap();
        assert_eq!(a.refusal(), Some("no pose served yet"));
        #[derive(Debug, Deserialize)]
        struct Overlay {
            timestamp_utc: String,
        }
        let a = Answer::read(br#"{"ok":true,"timestamp_utc":"t"}"#.to_vec(), p).unwrap();
        assert_eq!(
            a.parse::<Overlay>("overlay answer").unwrap().timestamp_utc,
            "t"
        );
        let a = Answer::read(br#"{"ok":true,"bytes":3}"#.to_vec(), p).unwrap();
        let e = a.parse::<Overlay>("overlay answer").unwrap_err();
        assert_eq!(
            e.to_string(),
            "c.sock: the daemon's overlay answer does not parse: missing field `timestamp_utc` at line 1 column 21"
        );
    }
}
