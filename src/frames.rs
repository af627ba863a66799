//! The node's stored frames (I/O shell): the burst median of each of the service's runs, kept in
//! the state directory so that later runs pool frames from different hours into their
//! refinement ([`crate::localize::pipeline::localize_pooled`]).
//!
//! A node stays where it is while the sun moves: shadows that lie across the road markings at
//! one hour lie elsewhere at the next, the markings stay. One frame's MI surface can hold
//! several optima the data cannot tell apart; frames hours apart, each on its own histogram,
//! agree about the road and disagree about the shadows.
//!
//! Each frame is one PNG, `frame-<unix seconds>-<camera fingerprint>.png`, written atomically
//! ([`crate::persist::write_atomic`]): a kill at any moment leaves every stored frame whole and
//! at most one temp file, removed by the next write. The name carries everything the pool checks
//! before decoding: when the frame was taken and which intrinsics it was taken with. Frames
//! closer in time than the spacing are one hour's light: the newer replaces the older, and the
//! pool leaves out those within the spacing of the run's own frame. The store is bounded in
//! count, age and bytes; the oldest go first.

use crate::camera::Camera;
use crate::error::{Error, Result};
use image::GrayImage;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The stored frames' bounds (`[daemon] pool-*`, checked by `validate`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoolLimits {
    /// Frames pooled into one run at most, the run's own included; as many are stored. 1 turns
    /// pooling off (nothing is stored).
    pub frames: usize,
    /// A stored frame older than this, hours, is dropped.
    pub max_age_h: f64,
    /// The stored frames' bytes on disk at most, MB (10⁶ bytes).
    pub max_disk_mb: f64,
    /// Frames taken closer together than this, minutes, are one light: the newer replaces the
    /// older, and the pool leaves out stored frames this close to the run's own.
    pub min_spacing_min: f64,
}

impl PoolLimits {
    /// The bounds `[daemon]` sets.
    pub fn of(d: &crate::config::DaemonConfig) -> Self {
        PoolLimits {
            frames: d.pool_frames,
            max_age_h: d.pool_max_age_h,
            max_disk_mb: d.pool_max_disk_mb,
            min_spacing_min: d.pool_min_spacing_min,
        }
    }
}

/// One stored frame as listed (not decoded): what `status` shows.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameEntry {
    /// File name in the frame directory.
    pub file: String,
    /// When the frame was taken, UTC (ISO 8601).
    pub taken_utc: String,
    /// Its size on disk, bytes.
    pub bytes: u64,
}

/// A stored frame decoded for a run.
#[derive(Debug, Clone)]
pub struct StoredFrame {
    /// Its listing.
    pub entry: FrameEntry,
    /// The frame.
    pub image: GrayImage,
}

/// A listed frame with the fields of its name.
struct Listed {
    entry: FrameEntry,
    unix_s: i64,
    fingerprint: String,
    path: PathBuf,
}

/// The camera's fingerprint in frame names: FNV-1a (64 bit, stable across builds, unlike std's
/// hasher) of its intrinsics as JSON, in hex. Two cameras of equal size but other intrinsics
/// (a re-calibration, a swapped lens) differ.
pub fn camera_fingerprint(camera: &Camera) -> String {
    let text = serde_json::to_string(camera).unwrap_or_default();
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in text.bytes() {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    format!("{h:016x}")
}

/// The frame directory of the service whose pose file is `pose`: `stored-frames/` beside it
/// (not `frames/`, the name a scene directory gives its camera frames next to its pose).
pub fn frame_dir(pose: &Path) -> PathBuf {
    pose.with_file_name("stored-frames")
}

/// The stored frames in one directory under one set of bounds.
#[derive(Debug, Clone)]
pub struct FrameStore {
    dir: PathBuf,
    limits: PoolLimits,
}

impl FrameStore {
    /// The store in `dir` (made on the first write) under `limits`.
    pub fn new(dir: &Path, limits: PoolLimits) -> Self {
        FrameStore {
            dir: dir.to_path_buf(),
            limits,
        }
    }

    /// Its directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Whether runs pool stored frames at all (`pool-frames` above 1).
    pub fn enabled(&self) -> bool {
        self.limits.frames > 1
    }

    /// Every stored frame whose name is a frame's, oldest first (files of other names are not
    /// the store's and are left alone).
    fn listed(&self) -> Vec<Listed> {
        let Ok(rd) = std::fs::read_dir(&self.dir) else {
            return Vec::new();
        };
        let mut v: Vec<Listed> = rd
            .filter_map(|e| e.ok())
            .filter_map(|e| {
                let file = e.file_name().to_str()?.to_string();
                let (unix_s, fingerprint) = parse_name(&file)?;
                let bytes = e.metadata().ok()?.len();
                Some(Listed {
                    entry: FrameEntry {
                        taken_utc: crate::posefile::format_utc(unix_s, None),
                        file,
                        bytes,
                    },
                    unix_s,
                    fingerprint,
                    path: e.path(),
                })
            })
            .collect();
        v.sort_by(|a, b| (a.unix_s, &a.entry.file).cmp(&(b.unix_s, &b.entry.file)));
        v
    }

    /// The stored frames, oldest first.
    pub fn list(&self) -> Vec<FrameEntry> {
        self.listed().into_iter().map(|l| l.entry).collect()
    }

    /// Store `image`, taken at `unix_s` with the camera of `fingerprint`, then enforce the
    /// bounds. Returns one line per frame dropped (spacing, age, count, bytes), for the log.
    /// Errors name the file when the frame cannot be encoded or written; stored frames are
    /// untouched then.
    pub fn put(&self, image: &GrayImage, fingerprint: &str, unix_s: i64) -> Result<Vec<String>> {
        if !self.enabled() {
            return Ok(Vec::new());
        }
        std::fs::create_dir_all(&self.dir).map_err(|e| Error::io(&self.dir, e))?;
        let path = self.dir.join(format!("frame-{unix_s}-{fingerprint}.png"));
        let mut png = Vec::new();
        image
            .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .map_err(|e| Error::input(&path, format!("cannot encode the frame as PNG: {e}")))?;
        crate::persist::write_atomic(&path, &png)?;
        Ok(self.enforce(&path, unix_s))
    }

    /// Drop what the bounds exclude once `newest` (taken at `unix_s`) is stored; temp files of
    /// killed writes go too.
    fn enforce(&self, newest: &Path, unix_s: i64) -> Vec<String> {
        self.remove_stale_temps();
        let spacing_s = self.limits.min_spacing_min * 60.0;
        let max_age_s = self.limits.max_age_h * 3600.0;
        let mut dropped = Vec::new();
        let mut kept = Vec::new();
        for l in self.listed() {
            let age = (unix_s - l.unix_s) as f64;
            let why = if l.path == newest {
                None
            } else if age.abs() < spacing_s {
                Some(format!(
                    "taken {:.0} min before the new frame, within [daemon] pool-min-spacing-min = {}",
                    age / 60.0,
                    self.limits.min_spacing_min
                ))
            } else if age > max_age_s {
                Some(format!(
                    "{:.1} h old, over [daemon] pool-max-age-h = {}",
                    age / 3600.0,
                    self.limits.max_age_h
                ))
            } else {
                None
            };
            match why {
                Some(w) => dropped.push((l, w)),
                None => kept.push(l),
            }
        }
        let max_bytes = self.limits.max_disk_mb * 1e6;
        let mut total: u64 = kept.iter().map(|l| l.entry.bytes).sum();
        while !kept.is_empty() && (kept.len() > self.limits.frames || total as f64 > max_bytes) {
            let l = kept.remove(0);
            total -= l.entry.bytes;
            let w = if kept.len() + 1 > self.limits.frames {
                format!(
                    "the oldest of {}, over [daemon] pool-frames = {}",
                    kept.len() + 1,
                    self.limits.frames
                )
            } else {
                format!(
                    "the oldest while the frames' {:.1} MB are over [daemon] pool-max-disk-mb = {}",
                    (total + l.entry.bytes) as f64 / 1e6,
                    self.limits.max_disk_mb
                )
            };
            dropped.push((l, w));
        }
        dropped
            .into_iter()
            .filter_map(|(l, w)| match std::fs::remove_file(&l.path) {
                Ok(()) => Some(format!("stored frame {} dropped: {w}", l.path.display())),
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
                Err(e) => Some(format!(
                    "stored frame {}: cannot drop it ({e}): {w}",
                    l.path.display()
                )),
            })
            .collect()
    }

    /// Temp files that writes killed mid-way left (`.frame-….png.tmp.PID.SEQ`, not of this
    /// process).
    fn remove_stale_temps(&self) {
        let Ok(rd) = std::fs::read_dir(&self.dir) else {
            return;
        };
        let own = format!(".tmp.{}.", std::process::id());
        for e in rd.filter_map(|e| e.ok()) {
            let name = e.file_name();
            let Some(n) = name.to_str() else { continue };
            if n.starts_with(".frame-") && n.contains(".png.tmp.") && !n.contains(&own) {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }

    /// The stored frames a run at `now_unix_s` with `camera` pools, newest first: at most
    /// `pool-frames − 1`, none within the spacing of `now_unix_s` nor older than the age bound.
    /// A frame taken with other intrinsics, of another size or that does not decode is skipped
    /// with one line naming it (second element); the run goes on without it.
    pub fn pool(&self, camera: &Camera, now_unix_s: i64) -> (Vec<StoredFrame>, Vec<String>) {
        use crate::camera::CameraModel;
        let mut frames = Vec::new();
        let mut skipped = Vec::new();
        if !self.enabled() {
            return (frames, skipped);
        }
        let fp = camera_fingerprint(camera);
        let spacing_s = self.limits.min_spacing_min * 60.0;
        let max_age_s = self.limits.max_age_h * 3600.0;
        for l in self.listed().into_iter().rev() {
            if frames.len() + 1 >= self.limits.frames {
                break;
            }
            let age = (now_unix_s - l.unix_s) as f64;
            if age < spacing_s || age > max_age_s {
                continue;
            }
            let name = l.path.display();
            if l.fingerprint != fp {
                skipped.push(format!(
                    "stored frame {name}: taken with other intrinsics (fingerprint {}, the camera's is {fp}); skipped",
                    l.fingerprint
                ));
                continue;
            }
            match crate::capture::load_gray(&l.path) {
                Ok(img) if (img.width(), img.height()) == (camera.width(), camera.height()) => {
                    frames.push(StoredFrame {
                        entry: l.entry,
                        image: img,
                    })
                }
                Ok(img) => skipped.push(format!(
                    "stored frame {name}: {}×{}, the camera is {}×{}; skipped",
                    img.width(),
                    img.height(),
                    camera.width(),
                    camera.height()
                )),
                Err(e) => skipped.push(format!("stored frame {name}: unreadable ({e}); skipped")),
            }
        }
        (frames, skipped)
    }

    /// Drop every stored frame (the camera moved, or a technician said so). Returns how many
    /// went; errors name the first file that could not be removed.
    pub fn clear(&self) -> Result<usize> {
        let mut n = 0;
        for l in self.listed() {
            match std::fs::remove_file(&l.path) {
                Ok(()) => n += 1,
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                Err(e) => return Err(Error::io(&l.path, e)),
            }
        }
        self.remove_stale_temps();
        Ok(n)
    }
}

/// `frame-<unix seconds>-<16 hex digits>.png` → (seconds, fingerprint).
fn parse_name(file: &str) -> Option<(i64, String)> {
    let rest = file.strip_prefix("frame-")?.strip_suffix(".png")?;
    let (t, fp) = rest.split_once('-')?;
    let t: i64 = t.parse().ok()?;
    (fp.len() == 16 && fp.bytes().all(|b| b.is_ascii_hexdigit()))
        .then(|| (t, fp.to_ascii_lowercase()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn limits() -> PoolLimits {
        PoolLimits {
            frames: 3,
            max_age_h: 24.0,
            max_disk_mb: 100.0,
            min_spacing_min: 30.0,
        }
    }

    fn camera(w: u32, h: u32) -> Camera {
        Camera::Mei(crate::camera::Mei::pinhole(w, h, 5.0, 5.0, 4.0, 3.0))
    }

    fn frame(w: u32, h: u32, v: u8) -> GrayImage {
        GrayImage::from_fn(w, h, |x, y| {
            image::Luma([v.wrapping_add((x * 7 + y * 3) as u8)])
        })
    }

    #[test]
    fn names_round_trip_and_others_are_not_frames() {
        assert_eq!(
            parse_name("frame-1700000000-00112233aabbccdd.png"),
            Some((1_700_000_000, "00112233aabbccdd".into()))
        );
        for bad in [
            "frame-1700000000-0011.png",
            "frame-x-00112233aabbccdd.png",
            ".frame-1-00112233aabbccdd.png.tmp.1.0",
            "pose.json",
            "frame-1-00112233aabbccdz.png",
        ] {
            assert_eq!(parse_name(bad), None, "{bad}");
        }
    }

    #[test]
    fn spacing_count_and_age_bound_the_store() {
        let d = tempfile::tempdir().unwrap();
        let s = FrameStore::new(d.path(), limits());
        let fp = "00000000000000aa";
        let t0 = 1_700_000_000;
        assert!(s.put(&frame(8, 6, 0), fp, t0).unwrap().is_empty());
        // Ten minutes later: the same light, the newer replaces the older.
        let dropped = s.put(&frame(8, 6, 1), fp, t0 + 600).unwrap();
        assert_eq!(dropped.len(), 1, "{dropped:?}");
        assert!(dropped[0].contains("pool-min-spacing-min"), "{dropped:?}");
        assert_eq!(s.list().len(), 1);
        s.put(&frame(8, 6, 2), fp, t0 + 3600).unwrap();
        s.put(&frame(8, 6, 3), fp, t0 + 7200).unwrap();
        let dropped = s.put(&frame(8, 6, 4), fp, t0 + 10800).unwrap();
        assert!(dropped[0].contains("pool-frames = 3"), "{dropped:?}");
        let names: Vec<String> = s.list().into_iter().map(|e| e.file).collect();
        assert_eq!(
            names,
            [t0 + 3600, t0 + 7200, t0 + 10800].map(|t| format!("frame-{t}-{fp}.png"))
        );
        // A day and more later every older frame is over the age bound.
        let dropped = s.put(&frame(8, 6, 5), fp, t0 + 10800 + 25 * 3600).unwrap();
        assert_eq!(dropped.len(), 3, "{dropped:?}");
        assert!(dropped.iter().all(|l| l.contains("pool-max-age-h")));
        assert_eq!(s.list().len(), 1);
    }

    #[test]
    fn the_disk_bound_drops_the_oldest() {
        let d = tempfile::tempdir().unwrap();
        let one = {
            let s = FrameStore::new(d.path(), limits());
            s.put(&frame(64, 48, 0), "00000000000000aa", 0).unwrap();
            let b = s.list()[0].bytes;
            s.clear().unwrap();
            b
        };
        let s = FrameStore::new(
            d.path(),
            PoolLimits {
                max_disk_mb: (2 * one + one / 2) as f64 / 1e6,
                ..limits()
            },
        );
        for k in 0..3 {
            s.put(&frame(64, 48, 0), "00000000000000aa", k * 3600)
                .unwrap();
        }
        let l = s.list();
        assert_eq!(l.len(), 2, "{l:?}");
        assert!(l.iter().map(|e| e.bytes).sum::<u64>() as f64 <= s.limits.max_disk_mb * 1e6);
        assert_eq!(l[0].file, "frame-3600-00000000000000aa.png");
    }

    #[test]
    fn the_pool_skips_what_does_not_fit_and_names_it() {
        let d = tempfile::tempdir().unwrap();
        let cam = camera(8, 6);
        let fp = camera_fingerprint(&cam);
        let s = FrameStore::new(
            d.path(),
            PoolLimits {
                frames: 10,
                ..limits()
            },
        );
        let t0 = 1_700_000_000;
        s.put(&frame(8, 6, 0), &fp, t0).unwrap();
        s.put(&frame(8, 6, 9), &fp, t0 + 3600).unwrap();
        s.put(&frame(10, 6, 0), &fp, t0 + 7200).unwrap();
        s.put(&frame(8, 6, 0), "0123456789abcdef", t0 + 10800)
            .unwrap();
        let bad = d.path().join(format!("frame-{}-{fp}.png", t0 + 14400));
        std::fs::write(&bad, b"\x89PNG\r\n\x1a\n garbage").unwrap();
        // Within the spacing of the run's own frame: left out, no word.
        s.put(&frame(8, 6, 0), &fp, t0 + 18000).unwrap();
        let (frames, skipped) = s.pool(&cam, t0 + 18000 + 60);
        let taken: Vec<&str> = frames.iter().map(|f| f.entry.file.as_str()).collect();
        assert_eq!(
            taken,
            [
                format!("frame-{}-{fp}.png", t0 + 3600),
                format!("frame-{t0}-{fp}.png")
            ]
        );
        assert_eq!(frames[0].image, frame(8, 6, 9));
        assert_eq!(skipped.len(), 3, "{skipped:?}");
        assert!(
            skipped[0].contains("unreadable") && skipped[0].contains(&bad.display().to_string())
        );
        assert!(skipped[1].contains("other intrinsics"), "{skipped:?}");
        assert!(
            skipped[2].contains("10×6, the camera is 8×6"),
            "{skipped:?}"
        );
        // Another camera's fingerprint changes with its intrinsics, not only its size.
        assert_ne!(fp, camera_fingerprint(&camera(8, 7)));
        assert_eq!(s.clear().unwrap(), 6);
        assert!(s.list().is_empty());
    }

    #[test]
    fn one_frame_means_no_pooling_and_nothing_stored() {
        let d = tempfile::tempdir().unwrap();
        let s = FrameStore::new(
            d.path(),
            PoolLimits {
                frames: 1,
                ..limits()
            },
        );
        s.put(&frame(8, 6, 0), "00000000000000aa", 0).unwrap();
        assert!(s.list().is_empty());
        assert!(!d.path().join("stored-frames").exists());
    }
}
