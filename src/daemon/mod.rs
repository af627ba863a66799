//! `infraloc daemon`: the node's service (I/O shell).
//!
//! Boot: load and validate the config (exit 78 if bad) → serve the stored pose at once, if any →
//! bind the control socket → localize (capture + GPS + tile → pipeline) in a worker thread →
//! offer the result to the [`PoseStore`] (a failed or worse result never replaces a good pose
//! unless a technician forces it) → `READY=1` once a pose is served or the service knows it is
//! degraded, with the reason in `STATUS=`. The main loop pings the watchdog, re-localizes on
//! request, on its schedule and after failures (backing off), runs the drift check, reloads the
//! config on SIGHUP (a bad file is reported and the running config kept) and ends cleanly on
//! SIGTERM. Every decision is one log line and is visible in `infraloc status`.

mod logging;
pub mod metrics;
pub(crate) mod notify;
mod policy;
pub mod status;

use crate::app::{camera_and_frame, Overrides, Run};
use crate::config::Config;
use crate::control::{self, Accepted, Progress, Refusal, Reply, Request};
use crate::error::{Error, Result};
use crate::frames::{FrameEntry, FrameStore};
use crate::localize::refine::drift::{
    drift_search, drift_search_with, DriftParams, DriftThresholds,
};
use crate::map::cache::load_tile;
use crate::posefile::{format_utc, PoseFile};
use crate::stage::StageName;
use crate::store::{Decision, PoseStore};
use policy::{Action, CrossCheck, Policy, Requested, Timing};
pub use status::State;
pub use status::Status;
use status::{
    Cleared, ConfigRefusal, DaemonAnswer, DriftCheck, DriftOutcome, DriftSearch, JobKind,
    OverlayAnswer, PoseAnswer, Queued, Refused, RunOutcome, RunResult, Running, Served, StageTime,
    Validated,
};
use std::path::{Path, PathBuf};
use std::sync::mpsc::{channel, Receiver, RecvTimeoutError, Sender};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

/// Longest the main loop sleeps between looks at its timers.
const TICK: Duration = Duration::from_millis(500);
/// How often the metrics file is rewritten when nothing happens and systemd asked for no
/// watchdog (with a watchdog, it is rewritten with every ping).
const METRICS_PERIOD: Duration = Duration::from_secs(60);
/// How long a technician's `relocalize --wait` may wait between two progress messages.
pub(crate) const WAIT_TIMEOUT: Duration = Duration::from_secs(30 * 60);

fn now_utc() -> String {
    let d = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap_or_default();
    format_utc(d.as_secs() as i64, Some(d.subsec_millis()))
}

/// What a technician waiting on a localization hears.
enum Answer {
    /// A stage started.
    Progress(StageName),
    /// The run's result.
    Done(Box<RunResult>),
    /// No result will come (the daemon is stopping).
    Refused(String),
}

enum Event {
    Terminate,
    Reload,
    Relocalize {
        force: bool,
        why: String,
        waiter: Option<Sender<Answer>>,
    },
    Progress(StageName),
    /// A localization's result, with the stored frames it pooled.
    LocalizeDone(Box<Result<(Run, Option<CrossCheck>)>>, Vec<FrameEntry>),
    DriftDone(Result<DriftSearch>),
}

/// The served pose's georeferencing as the `georef` request finds it.
#[derive(Clone)]
enum GeorefState {
    /// No pose served.
    NoPose,
    /// Ready: the pose, its camera and its tile's height layer in memory.
    Ready(Arc<crate::georef::ServedGeoref>),
    /// A pose is served but its tile or camera could not be read: why.
    Unavailable(String),
}

/// State shared with the control socket's threads.
struct Shared {
    status: Mutex<Status>,
    /// The latest successful pipeline run (for `dump-overlay`).
    last_run: Mutex<Option<Arc<Run>>>,
    /// What the `georef` request answers from.
    georef: Mutex<GeorefState>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // A panicking holder leaves plain data behind; the status is still worth serving.
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Run the service with the config at `config_path` until SIGTERM. Errors: a bad config
/// ([`Error::Config`], exit 78) or a control socket that cannot be bound.
pub(crate) fn run(config_path: &Path) -> Result<()> {
    // The same validation as `infraloc validate`: every problem, exit 78, before anything runs.
    let (cfg, warnings) = crate::preflight::load_for_service(config_path)?;
    // The one place the service chooses where its records (and the library's) go.
    logging::init();
    for w in warnings {
        tracing::warn!("config: {w}");
    }
    // The state directory is ours to create (systemd's StateDirectory= does it for the unit; a
    // hand-started service must not lose its first run to a missing directory).
    match crate::preflight::create_state_dir(&cfg) {
        Ok(Some(d)) => tracing::info!("created the state directory {} (0750)", d.display()),
        Ok(None) => {}
        Err(e) => {
            return Err(Error::config(
                config_path,
                format!("[output] pose: cannot create its directory: {e}"),
            ))
        }
    }
    // Temp files of writes a kill -9 interrupted are removed before anything is written.
    let history = cfg.output.pose.with_file_name(crate::store::HISTORY_FILE);
    let metrics_file = cfg.daemon.metrics_dir.as_deref().map(metrics::file_in);
    let lut = cfg.output.pose.with_file_name(crate::georef::LUT_FILE);
    let lut_meta = cfg.output.pose.with_file_name(crate::georef::LUT_META_FILE);
    for target in [
        Some(&cfg.output.pose),
        Some(&history),
        Some(&lut),
        Some(&lut_meta),
        cfg.output.report.as_ref(),
        cfg.output.overlay.as_ref(),
        metrics_file.as_ref(),
    ]
    .into_iter()
    .flatten()
    {
        for f in crate::persist::remove_stale_temps(target) {
            tracing::info!("removed {} (left by an interrupted write)", f.display());
        }
    }
    let store = PoseStore::at(&cfg.output.pose, cfg.daemon.history_len);
    let started = Instant::now();
    let mut status = Status {
        state: State::Starting,
        summary: "starting: first localization pending".into(),
        pid: std::process::id(),
        version: env!("CARGO_PKG_VERSION").to_string(),
        config: config_path.to_path_buf(),
        uptime_s: 0.0,
        served: None,
        running: None,
        last_result: None,
        last_drift_check: None,
        failures_in_a_row: 0,
        next_localize_in_s: None,
        next_drift_check_in_s: None,
        reload_error: None,
        stored_frames: Vec::new(),
    };
    let frames = FrameStore::new(
        &crate::frames::frame_dir(&cfg.output.pose),
        crate::frames::PoolLimits::of(&cfg.daemon),
    );
    status.stored_frames = frames.list();
    if !status.stored_frames.is_empty() {
        tracing::info!(
            "{} stored frames of earlier runs in {}",
            status.stored_frames.len(),
            frames.dir().display()
        );
    }
    let mut served: Option<PoseFile> = None;
    match store.current() {
        Ok(Some(p)) => {
            tracing::info!(
                "serving stored pose from {} (tile {})",
                p.timestamp_utc,
                p.tile_id
            );
            status.served = Some(Served::of(&store.pose_path(), &p));
            status.state = State::Ok;
            status.summary = format!(
                "ok: serving stored pose from {}; re-localizing",
                p.timestamp_utc
            );
            served = Some(p);
        }
        Ok(None) => tracing::info!("no stored pose yet"),
        Err(e) => tracing::warn!("stored pose unusable, not served: {e}"),
    }
    let shared = Arc::new(Shared {
        status: Mutex::new(status),
        last_run: Mutex::new(None),
        georef: Mutex::new(GeorefState::NoPose),
    });
    let (tx, rx) = channel::<Event>();
    let (listener, note) = control::bind(&cfg.daemon.socket)
        .map_err(|e| Error::config(config_path, format!("[daemon] socket: {e}")))?;
    if let Some(n) = note {
        tracing::warn!("{n}");
    }
    start_signals(tx.clone())?;
    let handler = make_handler(
        shared.clone(),
        store.clone(),
        frames.clone(),
        tx.clone(),
        config_path,
    );
    control::serve(listener, handler, control::Limits::default());
    tracing::info!(
        "control socket {} (mode {:o})",
        cfg.daemon.socket.display(),
        control::SOCKET_MODE
    );
    let mut d = Daemon {
        cfg,
        config_path: config_path.to_path_buf(),
        store,
        frames,
        shared,
        tx,
        policy: Policy::new(Instant::now(), served.is_some()),
        served,
        ready_sent: false,
        job_started: Instant::now(),
        waiters: Vec::new(),
        started,
        metrics_error: None,
    };
    if d.served.is_some() {
        d.serve_georef(None);
        // The stored pose is served already: the service is useful from this moment.
        d.send_ready();
    }
    let result = d.main_loop(rx);
    notify::notify("STOPPING=1");
    let _ = std::fs::remove_file(&d.cfg.daemon.socket);
    tracing::info!("stopped");
    result
}

/// The config as the service reads it at start and on reload, with its warnings.
fn load_config(path: &Path) -> Result<(Config, Vec<String>)> {
    crate::preflight::load_for_service(path)
}

fn start_signals(tx: Sender<Event>) -> Result<()> {
    use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
    let mut signals =
        signal_hook::iterator::Signals::new([SIGTERM, SIGINT, SIGHUP]).map_err(|source| {
            Error::System {
                what: "install signal handlers",
                source,
            }
        })?;
    std::thread::Builder::new()
        .name("signals".into())
        .spawn(move || {
            for s in signals.forever() {
                let ev = if s == SIGHUP {
                    Event::Reload
                } else {
                    Event::Terminate
                };
                if tx.send(ev).is_err() {
                    break;
                }
            }
        })
        .map_err(|source| Error::System {
            what: "start the signal thread",
            source,
        })?;
    Ok(())
}

fn make_handler(
    shared: Arc<Shared>,
    store: PoseStore,
    frames: FrameStore,
    tx: Sender<Event>,
    config_path: &Path,
) -> Arc<control::Handler<DaemonAnswer>> {
    let config_path = config_path.to_path_buf();
    let refused = |e: String| (DaemonAnswer::Refused(Refusal::new(e)), None);
    // mpsc::Sender is Sync since Rust 1.72, so the handler can be shared by client threads.
    Arc::new(move |req: Request, reply: &mut dyn Reply| match req {
        Request::Status {} => {
            let s = lock(&shared.status).clone();
            (DaemonAnswer::Status(Accepted::new(Box::new(s))), None)
        }
        Request::Georef {
            pixels,
            sigma_px,
            height_sigma_m,
        } => match lock(&shared.georef).clone() {
            GeorefState::Ready(g) => match g.answer(&pixels, sigma_px, height_sigma_m) {
                Ok(doc) => (DaemonAnswer::Georef(Accepted::new(doc)), None),
                Err(e) => refused(e),
            },
            GeorefState::NoPose => refused("no pose served yet".into()),
            GeorefState::Unavailable(e) => refused(format!("georef: {e}")),
        },
        Request::GetPose {} => match store.current() {
            Ok(Some(pose)) => (
                DaemonAnswer::Pose(Accepted::new(Box::new(PoseAnswer { pose }))),
                None,
            ),
            Ok(None) => refused("no pose served yet".into()),
            Err(e) => refused(e.to_string()),
        },
        Request::Validate {} => match load_config(&config_path) {
            Ok((_, warnings)) => (
                DaemonAnswer::Validated(Accepted::new(Validated {
                    config: config_path.clone(),
                    warnings,
                })),
                None,
            ),
            Err(e) => (
                DaemonAnswer::ConfigRefused(Refused::new(ConfigRefusal {
                    config: config_path.clone(),
                    error: e.to_string(),
                })),
                None,
            ),
        },
        Request::DumpOverlay {} => {
            let run = lock(&shared.last_run).clone();
            match run {
                Some(r) => match r.overlay_png() {
                    Ok(png) => (
                        DaemonAnswer::Overlay(Accepted::new(OverlayAnswer {
                            timestamp_utc: r.pose_file.timestamp_utc.clone(),
                            bytes: png.len(),
                        })),
                        Some(png),
                    ),
                    Err(e) => refused(e.to_string()),
                },
                None => refused("no localization has run since the daemon started; run `infraloc relocalize --wait` first".into()),
            }
        }
        Request::ClearFrames {} => match frames.clear() {
            Ok(n) => {
                tracing::warn!(
                    "{n} stored frames dropped on a technician's request; later runs pool only new frames"
                );
                lock(&shared.status).stored_frames = frames.list();
                (
                    DaemonAnswer::Cleared(Accepted::new(Cleared { cleared: n })),
                    None,
                )
            }
            Err(e) => refused(format!("stored frames: {e}")),
        },
        Request::Relocalize { wait, force } => {
            let (wtx, wrx) = channel();
            let ev = Event::Relocalize {
                force,
                why: "technician request".into(),
                waiter: wait.then_some(wtx),
            };
            if tx.send(ev).is_err() {
                return refused("the daemon is stopping".into());
            }
            if !wait {
                return (
                    DaemonAnswer::Queued(Accepted::new(Queued { queued: true })),
                    None,
                );
            }
            loop {
                match wrx.recv_timeout(WAIT_TIMEOUT) {
                    Ok(Answer::Progress(stage)) => {
                        if reply.progress(Progress { progress: stage }).is_err() {
                            // The technician went away; the run goes on.
                            return refused("client gone".into());
                        }
                    }
                    Ok(Answer::Done(r)) => return (DaemonAnswer::Result(r), None),
                    Ok(Answer::Refused(e)) => return refused(e),
                    Err(_) => {
                        return refused("no answer from the localization within 30 min".into())
                    }
                }
            }
        }
    })
}

struct Daemon {
    cfg: Config,
    config_path: PathBuf,
    store: PoseStore,
    /// The frames of earlier runs, pooled into later ones.
    frames: FrameStore,
    shared: Arc<Shared>,
    tx: Sender<Event>,
    served: Option<PoseFile>,
    ready_sent: bool,
    /// The decisions: what runs, what is queued, when the next runs are due.
    policy: Policy,
    job_started: Instant,
    /// Technicians waiting for the running (or next) localization.
    waiters: Vec<Sender<Answer>>,
    started: Instant,
    /// The last metrics write error logged (the same one is not logged again every minute).
    metrics_error: Option<String>,
}

impl Daemon {
    fn main_loop(&mut self, rx: Receiver<Event>) -> Result<()> {
        let watchdog = notify::watchdog_interval();
        let mut last_ping = Instant::now();
        if watchdog.is_some() {
            notify::notify("WATCHDOG=1");
        }
        let metrics_period = watchdog.map_or(METRICS_PERIOD, |w| w / 2);
        let mut last_metrics = Instant::now();
        self.write_metrics();
        loop {
            // The watchdog is fed from this loop, so a wedged loop is what systemd restarts.
            if let Some(w) = watchdog {
                if last_ping.elapsed() >= w / 2 {
                    notify::notify("WATCHDOG=1");
                    last_ping = Instant::now();
                }
            }
            // The metrics file's age (node_exporter's node_textfile_mtime_seconds) tells a
            // wedged or stopped service from a quiet one.
            if last_metrics.elapsed() >= metrics_period {
                self.write_metrics();
                last_metrics = Instant::now();
            }
            self.run_timers();
            self.refresh_status();
            let event = rx.recv_timeout(TICK);
            if event.is_ok() {
                // Every event changes what the status says: the metrics follow at once.
                last_metrics = Instant::now();
            }
            match event {
                Ok(Event::Terminate) => {
                    tracing::info!("SIGTERM: stopping");
                    for w in self.waiters.drain(..) {
                        let _ = w.send(Answer::Refused("the daemon is stopping".into()));
                    }
                    return Ok(());
                }
                Ok(Event::Reload) => self.reload(),
                Ok(Event::Relocalize { force, why, waiter }) => {
                    if let Some(w) = waiter {
                        // A technician joining a run in progress hears where it is at once.
                        let stage = self.lock_status().running.as_ref().map(|r| r.stage);
                        if let (Some(JobKind::Localize), Some(st)) = (&self.policy.job, stage) {
                            let _ = w.send(Answer::Progress(st));
                        }
                        self.waiters.push(w);
                    }
                    // Joined or queued requests are answered by the run's result.
                    if let Requested::Start(a) = self.policy.request(force, why) {
                        self.start(a);
                    }
                }
                Ok(Event::Progress(stage)) => {
                    self.waiters
                        .retain(|w| w.send(Answer::Progress(stage)).is_ok());
                    let mut s = lock(&self.shared.status);
                    if let Some(r) = s.running.as_mut() {
                        r.stage = stage;
                    }
                }
                Ok(Event::LocalizeDone(r, pooled)) => self.localize_done(*r, pooled),
                Ok(Event::DriftDone(r)) => self.drift_done(r),
                Err(RecvTimeoutError::Timeout) => continue,
                Err(RecvTimeoutError::Disconnected) => return Ok(()),
            }
            self.write_metrics();
        }
    }

    /// Rewrite the metrics file (`[daemon] metrics-dir`), if configured. A failure is logged
    /// (once per distinct error) and never stops the service.
    fn write_metrics(&mut self) {
        let Some(dir) = self.cfg.daemon.metrics_dir.clone() else {
            return;
        };
        self.refresh_status();
        let s = self.lock_status().clone();
        match metrics::write(&dir, &s) {
            Ok(()) => {
                if self.metrics_error.take().is_some() {
                    tracing::info!(
                        "metrics: {} written again",
                        metrics::file_in(&dir).display()
                    );
                }
            }
            Err(e) => {
                let e = format!("[daemon] metrics-dir: {e}");
                if self.metrics_error.as_deref() != Some(e.as_str()) {
                    tracing::warn!("metrics not written: {e}");
                    self.metrics_error = Some(e);
                }
            }
        }
    }

    fn run_timers(&mut self) {
        if let Some(a) = self.policy.due(Instant::now()) {
            self.start(a);
        }
    }

    /// Carry out a started job.
    fn start(&mut self, a: Action) {
        match a {
            Action::Localize { force, why } => self.start_localize(force, &why),
            Action::DriftCheck => self.start_drift(),
        }
    }

    fn lock_status(&self) -> MutexGuard<'_, Status> {
        lock(&self.shared.status)
    }

    fn refresh_status(&self) {
        let now = Instant::now();
        let left = |t: Option<Instant>| t.map(|t| t.saturating_duration_since(now).as_secs_f64());
        let mut s = self.lock_status();
        s.uptime_s = self.started.elapsed().as_secs_f64();
        s.next_localize_in_s = left(self.policy.next_localize);
        s.next_drift_check_in_s = left(self.policy.next_drift);
        if let Some(r) = s.running.as_mut() {
            r.seconds = self.job_started.elapsed().as_secs_f64();
        }
    }

    fn start_localize(&mut self, force: bool, why: &str) {
        tracing::info!("localizing ({why}{})", if force { ", forced" } else { "" });
        self.job_started = Instant::now();
        self.lock_status().running = Some(Running {
            job: JobKind::Localize,
            why: Some(why.to_string()),
            stage: StageName::Starting,
            seconds: 0.0,
        });
        let (cfg, path, tx) = (self.cfg.clone(), self.config_path.clone(), self.tx.clone());
        let frames = self.frames.clone();
        // A forced run is served whatever the served pose says, so it needs no cross-check.
        let served = self.served.clone().filter(|_| !force);
        let spawned = std::thread::Builder::new()
            .name("localize".into())
            .spawn(move || {
                let progress = |s: StageName| {
                    let _ = tx.send(Event::Progress(s));
                };
                let pool = crate::app::Pool {
                    store: &frames,
                    now_unix_s: std::time::SystemTime::now()
                        .duration_since(std::time::UNIX_EPOCH)
                        .map_or(0, |d| d.as_secs() as i64),
                    used: Mutex::new(Vec::new()),
                };
                let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                    let run = crate::app::run_pooled(
                        &cfg,
                        &path,
                        &Overrides::default(),
                        &progress,
                        Some(&pool),
                    )?;
                    let cc = served.as_ref().and_then(|p| {
                        progress(StageName::CrossCheck);
                        cross_check(&run, p, &cfg)
                    });
                    Ok((run, cc))
                }))
                .unwrap_or_else(|p| Err(internal_error("localize", p)));
                let pooled = pool.used.into_inner().unwrap_or_else(|e| e.into_inner());
                let _ = tx.send(Event::LocalizeDone(Box::new(r), pooled));
            });
        if let Err(source) = spawned {
            let _ = self.tx.send(Event::LocalizeDone(
                Box::new(Err(Error::System {
                    what: "start the localization thread",
                    source,
                })),
                Vec::new(),
            ));
        }
    }

    fn localize_done(&mut self, r: Result<(Run, Option<CrossCheck>)>, pooled: Vec<FrameEntry>) {
        let seconds = self.job_started.elapsed().as_secs_f64();
        let pooled_frames: Vec<String> = pooled.into_iter().map(|f| f.taken_utc).collect();
        self.lock_status().stored_frames = self.frames.list();
        let force = self.policy.forced();
        let finished = now_utc();
        let outcome = r.and_then(|(run, cc)| {
            let decision = match policy::keep_served(cc.as_ref(), force) {
                Some(why) => {
                    self.store
                        .record_kept(&run.pose_file, &why)
                        .map_err(|e| Error::Persist(e.to_string()))?;
                    Decision::Kept(why)
                }
                None => self
                    .store
                    .offer(&run.pose_file, force)
                    .map_err(|e| Error::Persist(e.to_string()))?,
            };
            Ok((run, decision))
        });
        let answer = match outcome {
            Ok((run, decision)) => {
                let (accepted, why) = match &decision {
                    Decision::Replaced(w) => (true, w.clone()),
                    Decision::Kept(w) => (false, w.clone()),
                };
                let c = run.pose_file.camera_center;
                tracing::info!(served = accepted, grade = run.pose_file.grade(), "localized in {seconds:.1} s: centre ({:.3}, {:.3}, {:.3}), score {:.4}, graded {}; {} ({why})",
                        c[0],
                        c[1],
                        c[2],
                        run.outcome.refinement.quality.nmi,
                        run.outcome.refinement.quality.grade,
                        if accepted { "served" } else { "not served" });
                if accepted {
                    self.served = Some(run.pose_file.clone());
                    self.serve_georef(Some(&run));
                    // A pose served after the drift alarm answers it.
                    if let Some(d) = self.lock_status().last_drift_check.as_mut() {
                        if matches!(&d.outcome, DriftOutcome::Ran(s) if s.verdict.moved) {
                            d.resolved = Some(format!("re-localized at {finished}"));
                        }
                    }
                    if let Err(e) = run.write_side_outputs(
                        self.cfg.output.report.as_ref(),
                        self.cfg.output.overlay.as_ref(),
                    ) {
                        tracing::warn!("report/overlay not written: {e}");
                    }
                }
                let result = RunResult {
                    finished_utc: finished,
                    seconds,
                    outcome: RunOutcome::Localized {
                        served: accepted,
                        decision: why,
                        camera_center: c,
                        yaw_pitch_roll_deg: run.pose_file.yaw_pitch_roll_deg,
                        score: run.pose_file.score(),
                        sigma: run.pose_file.sigma(),
                        skipped_tiles: run.skipped_tiles.clone(),
                        stages: run
                            .outcome
                            .stages
                            .iter()
                            .map(|s| StageTime {
                                name: s.name.name().to_string(),
                                seconds: s.seconds,
                            })
                            .collect(),
                    },
                    pooled_frames: pooled_frames.clone(),
                };
                for t in &run.skipped_tiles {
                    tracing::warn!("tile cache: skipped {}", t.reason);
                }
                *lock(&self.shared.last_run) = Some(Arc::new(run));
                self.policy.localized(
                    Instant::now(),
                    self.served.is_some(),
                    self.served.as_ref().is_some_and(|p| p.grade() == "coarse"),
                    &Timing::of(&self.cfg),
                );
                {
                    let mut s = self.lock_status();
                    s.failures_in_a_row = self.policy.failures_in_a_row;
                    s.last_result = Some(result.clone());
                }
                result
            }
            Err(e) => {
                let msg = e.to_string();
                let wait = self.policy.failed(Instant::now(), &Timing::of(&self.cfg));
                let n = self.policy.failures_in_a_row;
                self.lock_status().failures_in_a_row = n;
                tracing::error!(
                    failures_in_a_row = n,
                    "localization failed ({n} in a row): {msg}; {}; retry in {wait:.0} s",
                    if self.served.is_some() {
                        "last good pose kept"
                    } else {
                        "no pose served"
                    }
                );
                if let Err(e) = self.store.record_failure(&finished, &msg) {
                    tracing::warn!("history not written: {e}");
                }
                let result = RunResult {
                    finished_utc: finished,
                    seconds,
                    outcome: RunOutcome::Failed {
                        error: msg,
                        retry_in_s: wait,
                    },
                    pooled_frames,
                };
                self.lock_status().last_result = Some(result.clone());
                result
            }
        };
        for w in self.waiters.drain(..) {
            let _ = w.send(Answer::Done(Box::new(answer.clone())));
        }
        self.lock_status().running = None;
        self.update_state();
        self.send_ready();
    }

    fn start_drift(&mut self) {
        let Some(served) = self.served.clone() else {
            // The policy starts a drift check only while a pose is served.
            return;
        };
        tracing::info!("drift check");
        self.job_started = Instant::now();
        self.lock_status().running = Some(Running {
            job: JobKind::DriftCheck,
            why: None,
            stage: StageName::Capture,
            seconds: 0.0,
        });
        let (cfg, path, tx) = (self.cfg.clone(), self.config_path.clone(), self.tx.clone());
        let spawned = std::thread::Builder::new()
            .name("drift".into())
            .spawn(move || {
                let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                    drift_check(&cfg, &path, &served)
                }))
                .unwrap_or_else(|p| Err(internal_error("drift", p)));
                let _ = tx.send(Event::DriftDone(r));
            });
        if let Err(source) = spawned {
            let _ = self.tx.send(Event::DriftDone(Err(Error::System {
                what: "start the drift thread",
                source,
            })));
        }
    }

    fn drift_done(&mut self, r: Result<DriftSearch>) {
        let moved = r.as_ref().is_ok_and(|d| d.verdict.moved);
        self.policy
            .drift_checked(Instant::now(), moved, &Timing::of(&self.cfg));
        let outcome = match r {
            Ok(d) => {
                let v = &d.verdict;
                if v.moved {
                    tracing::warn!(
                        "drift check: camera moved ({}); re-localizing",
                        // As the JSON value was printed: the reason in quotes.
                        serde_json::to_string(&v.reason).unwrap_or_default()
                    );
                    // The stored frames show the old pose: pooled with the new view they
                    // would pull the new pose back.
                    match self.frames.clear() {
                        Ok(0) => {}
                        Ok(n) => {
                            tracing::warn!("drift check: {n} stored frames of the old pose dropped")
                        }
                        Err(e) => tracing::warn!(
                            "drift check: stored frames of the old pose not dropped: {e}"
                        ),
                    }
                    self.lock_status().stored_frames = self.frames.list();
                } else {
                    tracing::info!(
                        "drift check: ok (shift {:.3} m, yaw {:.3}°)",
                        v.shift_m,
                        v.yaw_deg
                    );
                }
                DriftOutcome::Ran(d)
            }
            Err(e) => {
                tracing::warn!("drift check could not run: {e}");
                DriftOutcome::NotRun {
                    moved: (),
                    error: e.to_string(),
                }
            }
        };
        {
            let mut s = self.lock_status();
            s.last_drift_check = Some(DriftCheck {
                checked_utc: now_utc(),
                outcome,
                resolved: None,
            });
            s.running = None;
        }
        self.update_state();
    }

    fn reload(&mut self) {
        match load_config(&self.config_path) {
            Ok((c, warnings)) => {
                for w in warnings {
                    tracing::warn!("reload: config: {w}");
                }
                if c.daemon.socket != self.cfg.daemon.socket {
                    tracing::warn!(
                        "reload: [daemon] socket changed; it takes effect at the next restart"
                    );
                }
                if c.output.pose != self.cfg.output.pose {
                    tracing::warn!(
                        "reload: [output] pose changed; it takes effect at the next restart"
                    );
                }
                let mut c = c;
                c.daemon.socket = self.cfg.daemon.socket.clone();
                c.output.pose = self.cfg.output.pose.clone();
                self.cfg = c;
                self.frames = FrameStore::new(
                    &crate::frames::frame_dir(&self.cfg.output.pose),
                    crate::frames::PoolLimits::of(&self.cfg.daemon),
                );
                self.lock_status().reload_error = None;
                tracing::info!("SIGHUP: config reloaded");
            }
            Err(e) => {
                tracing::error!("SIGHUP: config not reloaded, the running one stays: {e}");
                self.lock_status().reload_error = Some(e.to_string());
            }
        }
        self.update_state();
    }

    /// Make the served pose's georeferencing ready for the `georef` request, and write its lookup
    /// table beside the pose file (`[output] georef-lut-step-px`, 0: none). The camera and the
    /// height layer come from `run` when it produced the pose, else from the config and the tile
    /// cache. A failure is logged, and the request answers with it; the pose stays served.
    fn serve_georef(&mut self, run: Option<&Run>) {
        let Some(pose) = self.served.clone() else {
            *lock(&self.shared.georef) = GeorefState::NoPose;
            return;
        };
        let pose_path = self.store.pose_path();
        let built = (|| {
            let (camera, height) = match run {
                Some(r) => (r.camera.clone(), r.tile.height.clone()),
                None => {
                    let camera = crate::app::config_camera(&self.cfg, &self.config_path, None)?;
                    let tile = load_tile(&self.cfg.map.tiles.join(&pose.tile_id))?;
                    (camera, tile.height)
                }
            };
            crate::georef::ServedGeoref::new(&pose, &pose_path, camera, height, &pose.tile_id)
        })();
        let g = match built {
            Ok(g) => Arc::new(g),
            Err(e) => {
                tracing::warn!(
                    "georef unavailable for the pose from {}: {e}",
                    pose.timestamp_utc
                );
                *lock(&self.shared.georef) = GeorefState::Unavailable(e.to_string());
                return;
            }
        };
        *lock(&self.shared.georef) = GeorefState::Ready(g.clone());
        let step = self.cfg.output.georef_lut_step_px;
        if step == 0 {
            return;
        }
        let start = Instant::now();
        match g.write_lookup_table(&pose_path, step) {
            Ok(p) => tracing::info!(
                "georef lookup table {} written for the pose from {} ({step} px step, {:.2} s)",
                p.display(),
                g.timestamp_utc(),
                start.elapsed().as_secs_f64()
            ),
            Err(e) => tracing::warn!("georef lookup table not written: {e}"),
        }
    }

    /// Derive the state and summary line from what is known.
    fn update_state(&self) {
        let mut s = self.lock_status();
        let last_failed = s.last_result.as_ref().is_some_and(|r| !r.ok());
        let moved = s
            .last_drift_check
            .as_ref()
            .is_some_and(DriftCheck::unresolved_move);
        s.served = self
            .served
            .as_ref()
            .map(|p| Served::of(&self.store.pose_path(), p));
        let err = s
            .last_result
            .as_ref()
            .and_then(|r| r.error().map(str::to_string));
        let (state, summary) = match (&self.served, err) {
            (None, None) => (State::Starting, "starting: first localization pending".into()),
            (None, Some(e)) => (State::Failed, format!("failed: no pose served; {e}")),
            (Some(p), Some(e)) if last_failed => (
                State::Degraded,
                format!("degraded: serving pose from {}; last localization failed: {e}", p.timestamp_utc),
            ),
            (Some(p), _) if moved => (
                State::Degraded,
                format!("degraded: serving pose from {}; drift check found the camera moved, re-localizing", p.timestamp_utc),
            ),
            (Some(p), _) if p.grade() == "coarse" => (
                State::Ok,
                format!(
                    "ok: serving pose from {} (tile {}, coarse: {}); re-localizing to make it precise",
                    p.timestamp_utc,
                    p.tile_id,
                    p.grade_reason().as_deref().unwrap_or("σ over the precise limits")
                ),
            ),
            (Some(p), _) => (
                State::Ok,
                format!("ok: serving pose from {} (tile {}, {})", p.timestamp_utc, p.tile_id, p.grade()),
            ),
        };
        let summary = match &s.reload_error {
            Some(e) => format!("{summary}; config reload refused: {e}"),
            None => summary,
        };
        s.state = state;
        s.summary = summary;
    }

    /// `READY=1` the first time there is something to say; `STATUS=` every time. The metrics file
    /// is rewritten first, so that whoever the notification wakes reads the state it announces.
    fn send_ready(&mut self) {
        self.write_metrics();
        let summary = self.lock_status().summary.clone();
        if self.ready_sent {
            notify::notify(&format!("STATUS={summary}"));
        } else {
            notify::notify(&format!("READY=1\nSTATUS={summary}"));
            self.ready_sent = true;
        }
    }
}

fn internal_error(job: &'static str, p: Box<dyn std::any::Any + Send>) -> Error {
    let what = p
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "panic".into());
    Error::Internal { job, what }
}

/// The drift check: fresh frames, then [`drift_search`] around the served pose.
pub fn drift_check(cfg: &Config, config_path: &Path, served: &PoseFile) -> Result<DriftSearch> {
    let (camera, image) = camera_and_frame(cfg, config_path, &Overrides::default(), &|_| {})?;
    let tile = load_tile(&cfg.map.tiles.join(&served.tile_id))?;
    Ok(drift_search(
        &camera,
        image.as_raw(),
        &tile,
        &served.pose(),
        &drift_thresholds(cfg),
    )?)
}

/// The configured drift thresholds.
fn drift_thresholds(cfg: &Config) -> DriftThresholds {
    DriftThresholds {
        shift_m: cfg.daemon.drift_threshold_m,
        yaw_deg: cfg.daemon.drift_threshold_deg,
    }
}

/// Horizontal distance (m) and absolute yaw difference (deg) between two poses.
fn pose_distance(a: &crate::pose::CamFromMap, b: &crate::pose::CamFromMap) -> (f64, f64) {
    let d = crate::pose::offsets_between(a, b);
    (d[0].hypot(d[1]), d[3].abs())
}

/// The cross-check's search around the served pose keeps every LiDAR cell, unlike the drift
/// check: it compares the served pose's NMI with the new result's, which the localization scored
/// on every cell, and a thinned set's MI estimate runs high (fewer samples per histogram bin):
/// measured with `examples/drift_verdicts.rs`, the optimum's NMI on every third cell ran up to
/// 0.0027 above the localization's own, on every cell within ±0.0011, against a
/// [`policy::CROSS_CHECK_NMI_SLACK`] of 0.002. It runs only when a new result lands away from the
/// served pose.
const CROSS_CHECK_SEARCH: DriftParams = DriftParams {
    thin: 1,
    coarse_min_points: 20_000,
};

/// When a new result lands away from the served pose, ask the new frames whether the served
/// pose is still an MI peak that scores as well: then the camera has not moved and the new result
/// is a different (wrong) optimum, whatever its own score. Runs in the worker thread. `None` when
/// the two agree (or the check does not apply).
fn cross_check(run: &Run, served: &PoseFile, cfg: &Config) -> Option<CrossCheck> {
    let (d, dyaw) = pose_distance(&run.outcome.pose, &served.pose());
    if d < cfg.daemon.drift_threshold_m && dyaw < cfg.daemon.drift_threshold_deg {
        return None;
    }
    // A better grade is better evidence than the served pose's MI peak on one frame.
    let new = run.outcome.refinement.quality.grade.rank();
    if new > crate::localize::refine::verdict::rank_of(served.grade()) {
        return None;
    }
    if served.tile_id != run.tile.id {
        return None;
    }
    let search = drift_search_with(
        &run.camera,
        run.image.as_raw(),
        &run.tile,
        &served.pose(),
        &drift_thresholds(cfg),
        &CROSS_CHECK_SEARCH,
    )
    .map_err(|e| e.to_string());
    Some(CrossCheck {
        search,
        distance_m: d,
        yaw_deg_apart: dyaw,
        new_nmi: run.outcome.refinement.quality.nmi,
    })
}
