//! Crash-safe file writes (I/O shell): temp file in the same directory, fsync, rename over the
//! target, fsync the directory. A reader sees the old content or the new, never a partial file.

use crate::error::{Error, Result};
use std::fs::{self, File, OpenOptions};
use std::io::Write;
use std::path::Path;

/// The temp file name of `path`'s writes: `.NAME.tmp.PID.SEQ` beside it.
fn temp_prefix(name: &std::ffi::OsStr) -> String {
    format!(".{}.tmp.", name.to_string_lossy())
}

/// Atomically replace `path` with `bytes`. Errors name `path` (the file the caller asked for),
/// never the temp file, which is removed on failure. The file's mode is 0666 less the umask.
pub(crate) fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomic_mode(path, bytes, None)
}

/// [`write_atomic`] with the file's mode set to `mode` whatever the umask (the metrics file
/// must be readable by node_exporter's user while the service's umask is 0027).
pub(crate) fn write_atomic_mode(path: &Path, bytes: &[u8], mode: Option<u32>) -> Result<()> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let name = path.file_name().ok_or_else(|| {
        let not_file = std::io::Error::new(std::io::ErrorKind::InvalidInput, "not a file path");
        Error::io(path, not_file)
    })?;
    // Unique per process and call so concurrent writers never share a temp file.
    static SEQ: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let seq = SEQ.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let tmp = dir.join(format!("{}{}.{seq}", temp_prefix(name), std::process::id()));
    let result = (|| {
        let mut f = OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&tmp)
            .map_err(|e| Error::io(path, e))?;
        if let Some(m) = mode {
            use std::os::unix::fs::PermissionsExt;
            f.set_permissions(fs::Permissions::from_mode(m))
                .map_err(|e| Error::io(path, e))?;
        }
        f.write_all(bytes).map_err(|e| Error::io(path, e))?;
        f.sync_all().map_err(|e| Error::io(path, e))?;
        drop(f);
        fs::rename(&tmp, path).map_err(|e| Error::io(path, e))?;
        File::open(dir)
            .and_then(|d| d.sync_all())
            .map_err(|e| Error::io(dir, e))
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result
}

/// Remove the temp files that writes of `target` left behind when their process was killed
/// (kill -9, power loss): `.NAME.tmp.PID.SEQ` beside it whose PID is not a live process. Returns
/// the files removed. Called at the start of `localize` and of the service.
pub fn remove_stale_temps(target: &Path) -> Vec<std::path::PathBuf> {
    let (Some(dir), Some(name)) = (target.parent(), target.file_name()) else {
        return Vec::new();
    };
    let dir = if dir.as_os_str().is_empty() {
        Path::new(".")
    } else {
        dir
    };
    let prefix = temp_prefix(name);
    let Ok(entries) = fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut removed = Vec::new();
    for e in entries.filter_map(|e| e.ok()) {
        let file = e.file_name();
        let Some(rest) = file.to_str().and_then(|f| f.strip_prefix(&prefix)) else {
            continue;
        };
        let Some(pid) = rest.split('.').next().and_then(|p| p.parse::<i32>().ok()) else {
            continue;
        };
        if pid as u32 == std::process::id() || alive(pid) {
            continue;
        }
        if fs::remove_file(e.path()).is_ok() {
            removed.push(e.path());
        }
    }
    removed
}

/// Whether a process `pid` exists (signal 0: permission denied still means it exists).
fn alive(pid: i32) -> bool {
    if pid <= 0 {
        return false;
    }
    // SAFETY: kill with signal 0 only checks for existence and permission; no signal is sent.
    let rc = unsafe { libc::kill(pid, 0) };
    rc == 0 || std::io::Error::last_os_error().raw_os_error() == Some(libc::EPERM)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn replaces_content_and_leaves_no_temp() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("pose.json");
        write_atomic(&p, b"one").unwrap();
        write_atomic(&p, b"two").unwrap();
        assert_eq!(fs::read(&p).unwrap(), b"two");
        assert_eq!(fs::read_dir(d.path()).unwrap().count(), 1);
    }

    #[test]
    fn missing_directory_names_the_path() {
        let e = write_atomic(Path::new("/nonexistent-dir-xyz/pose.json"), b"x").unwrap_err();
        assert!(
            e.to_string().contains("/nonexistent-dir-xyz/pose.json"),
            "{e}"
        );
        assert!(!e.to_string().contains(".tmp."), "names the temp file: {e}");
    }

    #[test]
    fn stale_temps_of_dead_writers_are_removed() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("pose.json");
        // A dead writer's (pid far above any pid_max in use here), a live one's (ours: an
        // unfinished write in this process), another file's, and the target itself.
        let dead = d.path().join(".pose.json.tmp.2147483646.0");
        let ours = d
            .path()
            .join(format!(".pose.json.tmp.{}.7", std::process::id()));
        let other = d.path().join(".report.json.tmp.2147483646.0");
        for f in [&dead, &ours, &other, &p] {
            fs::write(f, "x").unwrap();
        }
        assert_eq!(remove_stale_temps(&p), vec![dead.clone()]);
        assert!(!dead.exists() && ours.exists() && other.exists() && p.exists());
    }
}
