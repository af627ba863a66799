//! What a configuration names, checked on this machine before any work (I/O shell).
//!
//! [`crate::config::Config::load`] checks the keys; this module opens what they point at: the
//! intrinsics parse (and the frames pooled at their size fit in memory), the frames source
//! exists, the tile cache holds a tile with a readable manifest, the match file parses, output
//! directories exist and are writable, the control socket's path is free. Every problem is
//! collected (each naming its `[section] key`), so a technician fixes them all in one pass. Things that may legitimately appear later (a camera or
//! receiver device that is plugged in after boot, the service's state and runtime directories,
//! which the service creates) are warnings, not problems.
//!
//! `infraloc validate`, the service at start and on reload (SIGHUP, `validate --running`) and
//! `localize` run the same checks; `localize` checks the outputs it was given on its command line
//! as well, before it captures anything.

use crate::config::{Config, FrameSourceKind, GpsSourceKind, MatcherKind};
use crate::error::{Error, Result};
use std::os::unix::fs::{FileTypeExt, MetadataExt};
use std::path::{Path, PathBuf};

/// Which run the config is checked for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Scope {
    /// A one-shot `localize`: the state directory must exist already (nobody creates it), the
    /// control socket is not used. (Only the tests check for it: `localize` runs the checks of
    /// `app`, not this one.)
    #[cfg(test)]
    Localize,
    /// The service (and `validate`): the state directory may be missing (the service creates
    /// it), the control socket's path must be usable.
    Service,
}

/// What the checks found.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub(crate) struct Findings {
    /// Problems that stop the node, one line each naming the key.
    pub problems: Vec<String>,
    /// Things to look at that do not stop it.
    pub warnings: Vec<String>,
}

impl Findings {}

/// The service's validation of the config at `path`: its keys ([`Config::load`]), then what they
/// name on this machine ([`check`] for the service). The config and its warnings, or every
/// problem (exit 78). `infraloc validate` runs this, and the service at start, on reload and for
/// `validate --running`.
pub(crate) fn load_for_service(path: &Path) -> Result<(Config, Vec<String>)> {
    let (cfg, mut problems) = Config::load_with_problems(path)?;
    let found = check(&cfg, Scope::Service);
    problems.extend(found.problems);
    Error::config_problems(path, problems)?;
    let mut warnings = found.warnings;
    warnings.extend(cfg.check());
    Ok((cfg, warnings))
}

/// The service's state directory: where the pose file lives.
pub(crate) fn state_dir(cfg: &Config) -> Option<&Path> {
    cfg.output
        .pose
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
}

/// Create the state directory (mode 0750) if it is missing; the created path, if any.
pub(crate) fn create_state_dir(cfg: &Config) -> Result<Option<PathBuf>> {
    let Some(dir) = state_dir(cfg) else {
        return Ok(None);
    };
    if dir.exists() {
        return Ok(None);
    }
    use std::os::unix::fs::DirBuilderExt;
    std::fs::DirBuilder::new()
        .recursive(true)
        .mode(0o750)
        .create(dir)
        .map_err(|e| Error::io(dir, e))?;
    // The umask may have taken bits the mode asked for; the mode is the intent.
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o750))
        .map_err(|e| Error::io(dir, e))?;
    Ok(Some(dir.to_path_buf()))
}

/// Check everything `cfg` names for a run of kind `scope`. `cfg` has been loaded (its keys
/// validated, its paths absolute).
pub(crate) fn check(cfg: &Config, scope: Scope) -> Findings {
    // Empty paths are the key validation's problem already; checking them here would only
    // repeat it in other words.
    let mut cfg = cfg.clone();
    let drop_empty = |p: &mut Option<PathBuf>| {
        if p.as_ref().is_some_and(|p| p.as_os_str().is_empty()) {
            *p = None;
        }
    };
    drop_empty(&mut cfg.camera.intrinsics_file);
    drop_empty(&mut cfg.camera.frames);
    drop_empty(&mut cfg.gps.path);
    drop_empty(&mut cfg.output.report);
    drop_empty(&mut cfg.output.overlay);
    drop_empty(&mut cfg.init.matcher_path);
    let cfg = &cfg;
    let mut f = Findings::default();
    if let Some(cam) = camera(cfg, &mut f) {
        pool_memory(cfg, &cam, &mut f);
    }
    gps(cfg, &mut f);
    tiles(cfg, &mut f);
    if cfg.init.matcher == MatcherKind::MatchFile {
        if let Some(p) = &cfg.init.matcher_path {
            match std::fs::read_to_string(p) {
                Ok(text) => {
                    if let Err(e) = crate::localize::init::matcher::MatchFile::parse(&text, p) {
                        f.problems
                            .push(format!("[init] matcher-path {}: {e}", p.display()));
                    }
                }
                Err(e) => f
                    .problems
                    .push(format!("[init] matcher-path {}: {e}", p.display())),
            }
        }
    }
    let state = state_dir(cfg).map(Path::to_path_buf);
    let o = &cfg.output;
    for (key, path) in [
        (
            "[output] pose",
            Some(&o.pose).filter(|p| !p.as_os_str().is_empty()),
        ),
        ("[output] report", o.report.as_ref()),
        ("[output] overlay", o.overlay.as_ref()),
    ] {
        if let Some(p) = path {
            let may_be_created =
                scope == Scope::Service && p.parent().is_some_and(|d| Some(d) == state.as_deref());
            output_path(key, p, may_be_created, &mut f);
        }
    }
    if !o.pose.as_os_str().is_empty() {
        stored_pose(&o.pose, &mut f);
    }
    if scope == Scope::Service && !cfg.daemon.socket.as_os_str().is_empty() {
        socket(&cfg.daemon.socket, &mut f);
    }
    if let Some(d) = cfg.daemon.metrics_dir.as_ref() {
        if scope == Scope::Service && !d.as_os_str().is_empty() {
            metrics_dir(d, &mut f);
        }
    }
    f
}

/// `[output] pose`, when a pose is stored there already: its rotation as the readers take it
/// ([`crate::orthonormal`]). A re-orthonormalised rotation is said once, and a pose file the
/// readers refuse is named, both as warnings: the file is the service's own state, which the
/// next localization replaces, not something the config asks for.
fn stored_pose(p: &Path, f: &mut Findings) {
    let Ok(text) = std::fs::read_to_string(p) else {
        return;
    };
    match crate::posefile::parse_pose(&text, p) {
        Ok(r) => {
            if let Some(n) = r.note {
                f.warnings.push(format!("[output] pose: {n}"));
            }
        }
        Err(e) => f.warnings.push(format!("[output] pose: {e}")),
    }
}

/// `[daemon] metrics-dir`: node_exporter's textfile directory, which must exist (the service
/// does not create another program's directory) and be writable by the service.
fn metrics_dir(d: &Path, f: &mut Findings) {
    let key = "[daemon] metrics-dir";
    match std::fs::metadata(d) {
        Err(e) => f.problems.push(format!(
            "{key} {}: {e} (node_exporter's textfile directory; create it or remove the key)",
            d.display()
        )),
        Ok(m) if !m.is_dir() => f
            .problems
            .push(format!("{key} {} is not a directory", d.display())),
        Ok(m) => {
            if let Some(w) = not_writable(d, &m) {
                if is_ours(&m) {
                    f.problems.push(format!("{key}: {w}"));
                } else {
                    f.warnings.push(format!(
                        "{key}: {w} by you (uid {}); the service's user must be able to write it (`validate --running` asks the service itself)",
                        euid()
                    ));
                }
            }
        }
    }
}

/// Check an output file path: not a directory, its directory exists (or, if `may_be_created`,
/// will be created by the service) and is writable. Used for the config's outputs and for
/// `localize`'s `--out`, `--report` and `--overlay`.
pub(crate) fn output_path(key: &str, p: &Path, may_be_created: bool, f: &mut Findings) {
    if p.is_dir() {
        f.problems.push(format!(
            "{key} {} is a directory; give a file path",
            p.display()
        ));
        return;
    }
    if p.file_name().is_none() {
        f.problems
            .push(format!("{key} {} is not a file path", p.display()));
        return;
    }
    let dir = match p.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    match std::fs::metadata(dir) {
        Err(_) if may_be_created => f.warnings.push(format!(
            "{key}: directory {} does not exist yet; the service creates it at start",
            dir.display()
        )),
        Err(e) => f.problems.push(format!(
            "{key} {}: directory {}: {e}",
            p.display(),
            dir.display()
        )),
        Ok(m) if !m.is_dir() => f.problems.push(format!(
            "{key} {}: {} is not a directory",
            p.display(),
            dir.display()
        )),
        Ok(m) => {
            if let Some(w) = not_writable(dir, &m) {
                // Another user's directory (the service's, 0750) cannot be judged from a
                // technician's account: say so instead of failing.
                if is_ours(&m) {
                    f.problems.push(format!("{key} {}: {w}", p.display()));
                } else {
                    f.warnings.push(format!(
                        "{key} {}: {w} by you (uid {}); the directory belongs to uid {}, which must be able to write it (`validate --running` asks the service itself)",
                        p.display(),
                        euid(),
                        m.uid()
                    ));
                }
            }
        }
    }
}

fn euid() -> u32 {
    // SAFETY: geteuid has no preconditions and cannot fail.
    unsafe { libc::geteuid() }
}

fn is_ours(m: &std::fs::Metadata) -> bool {
    let me = euid();
    me == 0 || m.uid() == me
}

/// Why `dir` is not writable by this process, if it is not.
fn not_writable(dir: &Path, _m: &std::fs::Metadata) -> Option<String> {
    use std::os::unix::ffi::OsStrExt;
    let c = std::ffi::CString::new(dir.as_os_str().as_bytes()).ok()?;
    // SAFETY: `c` is a valid NUL-terminated path for the duration of the call.
    let rc = unsafe { libc::access(c.as_ptr(), libc::W_OK | libc::X_OK) };
    (rc != 0).then(|| {
        format!(
            "directory {} is not writable ({})",
            dir.display(),
            std::io::Error::last_os_error()
        )
    })
}

/// The `[camera]` checks; the intrinsics when they parse.
fn camera(cfg: &Config, f: &mut Findings) -> Option<crate::camera::Camera> {
    let c = &cfg.camera;
    let mut cam = None;
    if let Some(p) = &c.intrinsics_file {
        let file = strip_selector(p);
        match std::fs::metadata(&file) {
            Err(e) => f
                .problems
                .push(format!("[camera] intrinsics-file {}: {e}", file.display())),
            Ok(m) if m.is_dir() => f.problems.push(format!(
                "[camera] intrinsics-file {} is a directory, not an intrinsics file",
                file.display()
            )),
            Ok(_) => match crate::camera::load_camera(p) {
                Err(e) => f.problems.push(format!("[camera] intrinsics-file: {e}")),
                Ok(c) => cam = Some(c),
            },
        }
    }
    match c.source {
        FrameSourceKind::File => {
            if let Some(p) = &c.frames {
                let mut src = crate::capture::FileSource::new(p);
                if let Err(e) = crate::capture::FrameSource::open(&mut src) {
                    f.problems
                        .push(format!("[camera] frames {}: {}", p.display(), e.detail));
                }
            }
        }
        // A source compiled out of this build is a config problem ([`Config::problems`]).
        FrameSourceKind::V4l2 => {
            if let Some(d) = &c.device {
                device("[camera] device", d, "capture retries until it appears", f);
            }
        }
        FrameSourceKind::Aravis => {}
    }
    cam
}

/// `[daemon] pool-frames` against this machine's memory ([`pool_memory_warning`]).
fn pool_memory(cfg: &Config, cam: &crate::camera::Camera, f: &mut Findings) {
    use crate::camera::CameraModel;
    let total = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|t| mem_total_bytes(&t));
    if let Some(w) = total
        .and_then(|t| pool_memory_warning(cfg.daemon.pool_frames, cam.width(), cam.height(), t))
    {
        f.warnings.push(w);
    }
}

/// Memory a pooled refinement holds per frame and pixel, bytes: six 5 MP hours took 470–511 MB
/// against one burst's 114 MB (docs/benchmarks.md, "Pooled refinement"), about 75 MB for each
/// frame of 5.0 Mpx pooled.
const POOL_BYTES_PER_PIXEL: f64 = 15.0;

/// A warning when pooling `frames` frames of `width` × `height` would take over half of the
/// machine's `total` bytes of memory in one run: a node that runs out of memory mid-run is
/// killed and restarted into the same run.
fn pool_memory_warning(frames: usize, width: u32, height: u32, total: u64) -> Option<String> {
    let need = frames as f64 * POOL_BYTES_PER_PIXEL * f64::from(width) * f64::from(height);
    let gb = |b: f64| b / 1e9;
    (frames > 1 && need > 0.5 * total as f64).then(|| {
        format!(
            "[daemon] pool-frames = {frames}: pooling {frames} frames of {width}×{height} takes about {:.1} GB in one run, over half of this machine's {:.1} GB; lower pool-frames",
            gb(need),
            gb(total as f64)
        )
    })
}

/// `MemTotal` of `/proc/meminfo`'s text, bytes.
fn mem_total_bytes(meminfo: &str) -> Option<u64> {
    let line = meminfo.lines().find(|l| l.starts_with("MemTotal:"))?;
    let mut it = line["MemTotal:".len()..].split_whitespace();
    let n: u64 = it.next()?.parse().ok()?;
    match it.next() {
        Some("kB") => n.checked_mul(1024),
        None => Some(n),
        Some(_) => None,
    }
}

/// `file.yaml:cam1` (a camchain's named camera) → `file.yaml`, when the whole path is not a file.
fn strip_selector(p: &Path) -> PathBuf {
    if p.exists() {
        return p.to_path_buf();
    }
    let s = p.to_string_lossy();
    match s.rsplit_once(':') {
        Some((file, sel)) if !sel.contains('/') && !file.is_empty() => PathBuf::from(file),
        _ => p.to_path_buf(),
    }
}

/// A device node: missing is a warning (it may be plugged in later), anything but a character
/// device is a problem.
fn device(key: &str, d: &str, later: &str, f: &mut Findings) {
    match std::fs::metadata(d) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => f
            .warnings
            .push(format!("{key} {d} does not exist (yet): {later}")),
        Err(e) => f.problems.push(format!("{key} {d}: {e}")),
        Ok(m) if !m.file_type().is_char_device() => f
            .problems
            .push(format!("{key} {d} is not a character device")),
        Ok(_) => {}
    }
}

fn gps(cfg: &Config, f: &mut Findings) {
    let g = &cfg.gps;
    match g.source {
        GpsSourceKind::NmeaFile => {
            if let Some(p) = &g.path {
                match std::fs::File::open(p).and_then(|h| h.metadata()) {
                    Err(e) => f.problems.push(format!("[gps] path {}: {e}", p.display())),
                    Ok(m) if !m.is_file() => f.problems.push(format!(
                        "[gps] path {} is not a file (an NMEA log)",
                        p.display()
                    )),
                    Ok(_) => {}
                }
            }
        }
        GpsSourceKind::Serial => {
            if let Some(d) = &g.device {
                let later = if g.fallback_wgs84.is_some() {
                    "the prior uses fallback-wgs84 until it appears"
                } else {
                    "no prior until it appears"
                };
                device("[gps] device", d, later, f);
            }
        }
        GpsSourceKind::Fixed => {}
    }
}

fn tiles(cfg: &Config, f: &mut Findings) {
    let dir = &cfg.map.tiles;
    let key = "[map] tiles";
    if dir.as_os_str().is_empty() {
        return;
    }
    let entries = match std::fs::metadata(dir) {
        Err(e) => {
            f.problems.push(format!(
                "{key} {}: {e} (import a tile with `infraloc tile import`)",
                dir.display()
            ));
            return;
        }
        Ok(m) if !m.is_dir() => {
            f.problems.push(format!(
                "{key} {} is not a directory (the tile cache is a directory of tile directories)",
                dir.display()
            ));
            return;
        }
        Ok(_) => match std::fs::read_dir(dir) {
            Ok(e) => e,
            Err(e) => {
                f.problems.push(format!("{key} {}: {e}", dir.display()));
                return;
            }
        },
    };
    let mut good = 0;
    let mut bad = 0;
    let mut tile_dirs: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.is_dir()
                && !p
                    .file_name()
                    .is_some_and(|n| n.to_string_lossy().starts_with('.'))
        })
        .collect();
    tile_dirs.sort();
    for t in &tile_dirs {
        match crate::map::cache::read_manifest(t) {
            Ok(_) => good += 1,
            Err(e) => {
                bad += 1;
                f.warnings.push(format!(
                    "{key}: tile {} is skipped: {e}",
                    t.file_name().unwrap_or_default().to_string_lossy()
                ));
            }
        }
    }
    if good == 0 {
        f.problems.push(format!(
            "{key} {}: no tile with a readable manifest ({bad} unreadable); import one with `infraloc tile import`",
            dir.display()
        ));
        return;
    }
    // A known position the cache should cover: the surveyed fallback.
    if let Some([lat, lon]) = cfg.gps.fallback_wgs84 {
        if let Err(e) = crate::map::cache::find_tile(dir, lat, lon, cfg.map.search_margin_m) {
            f.warnings.push(format!("{key}: for fallback-wgs84: {e}"));
        }
    }
}

fn socket(p: &Path, f: &mut Findings) {
    let key = "[daemon] socket";
    match std::fs::symlink_metadata(p) {
        Ok(m) if m.is_dir() => f.problems.push(format!(
            "{key} {} is a directory; give the socket's file path",
            p.display()
        )),
        Ok(m) if !m.file_type().is_socket() => f.problems.push(format!(
            "{key} {} exists and is not a socket; the service will not replace it",
            p.display()
        )),
        _ => {}
    }
    if let Some(dir) = p.parent().filter(|d| !d.as_os_str().is_empty()) {
        match std::fs::metadata(dir) {
            Err(_) => f.warnings.push(format!(
                "{key}: directory {} does not exist yet; the service creates it (0750) at start",
                dir.display()
            )),
            Ok(m) if !m.is_dir() => f.problems.push(format!(
                "{key} {}: {} is not a directory",
                p.display(),
                dir.display()
            )),
            Ok(_) => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pooling_more_frames_than_memory_holds_is_a_warning_naming_the_key() {
        let meminfo = "MemTotal:        2009980 kB\nMemFree:          100000 kB\n";
        let total = mem_total_bytes(meminfo).unwrap();
        assert_eq!(total, 2_009_980 * 1024);
        // 32 frames of 5 MP: about 2.4 GB on a 2 GB node.
        let w = pool_memory_warning(32, 2448, 2048, total).unwrap();
        assert!(
            w.starts_with("[daemon] pool-frames = 32:") && w.contains("2448×2048"),
            "{w}"
        );
        assert!(!w.contains('\n'));
        // The default six on the same node, and one frame anywhere, are quiet.
        assert_eq!(pool_memory_warning(6, 2448, 2048, total), None);
        assert_eq!(pool_memory_warning(1, 2448, 2048, 1), None);
        assert_eq!(mem_total_bytes("MemFree: 1 kB\n"), None);
        assert_eq!(mem_total_bytes("MemTotal: x kB\n"), None);
    }

    fn cfg_in(dir: &Path, extra: &str) -> Config {
        let text = format!(
            "[camera]\nintrinsics-file = \"cam.yaml\"\nsource = \"file\"\nframes = \"frames\"\n\
             [gps]\nsource = \"fixed\"\nfallback-wgs84 = [42.0, -83.0]\n\
             [output]\npose = \"state/pose.json\"\n[daemon]\nsocket = \"run/c.sock\"\n{extra}"
        );
        let p = dir.join("c.toml");
        std::fs::write(&p, text).unwrap();
        Config::load(&p).unwrap()
    }

    #[test]
    fn every_missing_thing_is_one_problem_naming_its_key() {
        let d = tempfile::tempdir().unwrap();
        let f = check(&cfg_in(d.path(), ""), Scope::Service);
        let keys: Vec<&str> = f
            .problems
            .iter()
            .map(|p| p.split(' ').take(2).collect::<Vec<_>>())
            .map(|v| {
                if v[1].starts_with("intr") {
                    "intrinsics"
                } else {
                    v[1]
                }
            })
            .collect();
        assert_eq!(keys, ["intrinsics", "frames", "tiles"], "{f:?}");
        // The state and runtime directories are the service's to create: warnings.
        assert!(
            f.warnings
                .iter()
                .any(|w| w.contains("[output] pose") && w.contains("the service creates it")),
            "{f:?}"
        );
        assert!(
            f.warnings.iter().any(|w| w.starts_with("[daemon] socket")),
            "{f:?}"
        );
        // A one-shot localize has nobody to create it.
        let f = check(&cfg_in(d.path(), ""), Scope::Localize);
        assert!(
            f.problems.iter().any(|p| p.starts_with("[output] pose")),
            "{f:?}"
        );
    }

    #[test]
    fn a_stored_pose_with_a_six_decimal_rotation_is_one_warning() {
        let d = tempfile::tempdir().unwrap();
        std::fs::create_dir_all(d.path().join("state")).unwrap();
        let pose = d.path().join("state/pose.json");
        let rot = "[[0.999974,-0.007141,-0.000089],[0.007141,0.999969,-0.003247],[0.000112,0.003247,0.999995]]";
        std::fs::write(
            &pose,
            format!(r#"{{"rotation_cam_from_map":{rot},"translation_cam_from_map":[0,0,5]}}"#),
        )
        .unwrap();
        let f = check(&cfg_in(d.path(), ""), Scope::Service);
        let notes: Vec<&String> = f
            .warnings
            .iter()
            .filter(|w| w.contains("re-orthonormalised"))
            .collect();
        assert_eq!(notes.len(), 1, "{f:?}");
        assert!(
            notes[0].starts_with(&format!(
                "[output] pose: {}: rotation_cam_from_map re-orthonormalised",
                pose.display()
            )),
            "{f:?}"
        );
        assert!(!f.problems.iter().any(|p| p.contains("pose")), "{f:?}");
        // Off by 1e-3: still only a warning (the service's own state), naming the field.
        std::fs::write(
            &pose,
            format!(
                r#"{{"rotation_cam_from_map":{},"translation_cam_from_map":[0,0,5]}}"#,
                rot.replace("0.999974", "0.998974")
            ),
        )
        .unwrap();
        let f = check(&cfg_in(d.path(), ""), Scope::Service);
        assert!(
            f.warnings
                .iter()
                .any(|w| w.contains("rotation_cam_from_map is not a rotation")),
            "{f:?}"
        );
    }

    #[test]
    fn directories_where_files_belong_are_problems() {
        let d = tempfile::tempdir().unwrap();
        std::fs::create_dir_all(d.path().join("cam.yaml")).unwrap();
        std::fs::write(d.path().join("tiles"), "not a dir").unwrap();
        std::fs::create_dir_all(d.path().join("state/pose.json")).unwrap();
        std::fs::create_dir_all(d.path().join("run")).unwrap();
        std::fs::write(d.path().join("run/c.sock"), "").unwrap();
        let f = check(&cfg_in(d.path(), ""), Scope::Service);
        let all = f.problems.join("\n");
        for want in [
            "intrinsics-file",
            "is a directory, not an intrinsics file",
            "[map] tiles",
            "is not a directory",
            "[output] pose",
            "[daemon] socket",
            "is not a socket",
        ] {
            assert!(all.contains(want), "{want}: {all}");
        }
    }

    #[test]
    fn state_dir_is_created_0750() {
        use std::os::unix::fs::PermissionsExt;
        let d = tempfile::tempdir().unwrap();
        let c = cfg_in(d.path(), "");
        assert_eq!(
            create_state_dir(&c).unwrap().as_deref(),
            Some(d.path().join("state").as_path())
        );
        let m = std::fs::metadata(d.path().join("state")).unwrap();
        assert_eq!(m.permissions().mode() & 0o777, 0o750);
        assert_eq!(create_state_dir(&c).unwrap(), None);
    }

    #[test]
    fn metrics_dir_must_be_an_existing_directory() {
        let d = tempfile::tempdir().unwrap();
        let problems = |extra: &str| check(&cfg_in(d.path(), extra), Scope::Service).problems;
        let metrics: Vec<String> = problems("metrics-dir = \"textfile\"")
            .into_iter()
            .filter(|p| p.starts_with("[daemon] metrics-dir"))
            .collect();
        assert_eq!(metrics.len(), 1, "{metrics:?}");
        assert!(metrics[0].contains("textfile"), "{metrics:?}");
        std::fs::write(d.path().join("textfile"), "").unwrap();
        let p = problems("metrics-dir = \"textfile\"").join("\n");
        assert!(
            p.contains("[daemon] metrics-dir") && p.contains("is not a directory"),
            "{p}"
        );
        std::fs::remove_file(d.path().join("textfile")).unwrap();
        std::fs::create_dir(d.path().join("textfile")).unwrap();
        let p = problems("metrics-dir = \"textfile\"");
        assert!(!p.iter().any(|p| p.contains("metrics-dir")), "{p:?}");
        // A one-shot localize writes no metrics.
        let f = check(&cfg_in(d.path(), "metrics-dir = \"nope\""), Scope::Localize);
        assert!(
            !f.problems.iter().any(|p| p.contains("metrics-dir")),
            "{f:?}"
        );
    }
}
