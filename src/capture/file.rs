//! Replay source: one image, or a directory of images read in name order.
//!
//! At the end of a directory the source starts again from the first image: a node replaying a
//! recorded burst must keep localizing on every trigger, and a scene directory from
//! `infraloc simulate` then behaves like a camera that keeps delivering the same scene. The
//! directory is listed when the source is opened, so files added later are seen after a reopen.

use super::{Fault, Frame, FrameSource, GrabError};
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime};

/// Extensions the `image` build of this crate decodes (png, jpeg, tiff features).
const IMAGE_EXTENSIONS: [&str; 5] = ["png", "jpg", "jpeg", "tif", "tiff"];

/// Images from a file or directory.
#[derive(Debug)]
pub(crate) struct FileSource {
    path: PathBuf,
    name: String,
    files: Vec<PathBuf>,
    next: usize,
    sequence: u64,
}

impl FileSource {
    /// A source over `path` (an image or a directory); nothing is read until `open`.
    pub(crate) fn new(path: &Path) -> FileSource {
        FileSource {
            path: path.to_path_buf(),
            name: path.display().to_string(),
            files: Vec::new(),
            next: 0,
            sequence: 0,
        }
    }

    /// The images in replay order (after `open`).
    pub(crate) fn files(&self) -> &[PathBuf] {
        &self.files
    }
}

/// Read an image file as 8-bit gray ([`super::convert::to_gray`]): the one way a frame, a
/// scene's frame or a command's `--image` is read from disk. Errors name the file.
pub(crate) fn load_gray(path: &Path) -> crate::Result<image::GrayImage> {
    let img = image::open(path)
        .map_err(|e| crate::Error::input(path, format!("cannot read image: {e}")))?;
    Ok(super::convert::to_gray(img))
}

fn is_image(p: &Path) -> bool {
    p.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| IMAGE_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
}

impl FrameSource for FileSource {
    fn device(&self) -> &str {
        &self.name
    }

    fn open(&mut self) -> Result<(), GrabError> {
        let meta = std::fs::metadata(&self.path).map_err(|e| GrabError::from_io(&e))?;
        self.files = if meta.is_dir() {
            let mut files: Vec<PathBuf> = std::fs::read_dir(&self.path)
                .map_err(|e| GrabError::from_io(&e))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.is_file() && is_image(p))
                .collect();
            files.sort();
            if files.is_empty() {
                return Err(GrabError::new(
                    Fault::Absent,
                    format!("no {} images in the directory", IMAGE_EXTENSIONS.join("/")),
                ));
            }
            files
        } else {
            vec![self.path.clone()]
        };
        self.next = 0;
        Ok(())
    }

    fn grab(&mut self, _timeout: Duration) -> Result<Frame, GrabError> {
        if self.files.is_empty() {
            return Err(GrabError::new(Fault::Io, "grab before open"));
        }
        let path = &self.files[self.next];
        let with_name = |e: GrabError| GrabError {
            detail: format!("{}: {}", path.display(), e.detail),
            ..e
        };
        let bytes = std::fs::read(path).map_err(|e| with_name(GrabError::from_io(&e)))?;
        let image = image::load_from_memory(&bytes)
            .map(super::convert::to_gray)
            .map_err(|e| with_name(GrabError::new(Fault::Corrupt, e.to_string())))?;
        self.next = (self.next + 1) % self.files.len();
        self.sequence += 1;
        Ok(Frame {
            image,
            timestamp: SystemTime::now(),
            sequence: self.sequence,
        })
    }

    fn close(&mut self) {
        self.files.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::capture::{capture, CaptureSettings, Clock, RetryPolicy};
    use image::GrayImage;

    struct NoWait;
    impl Clock for NoWait {
        fn now(&self) -> Duration {
            Duration::ZERO
        }
        fn sleep(&self, _: Duration) {}
    }

    fn write(dir: &Path, name: &str, v: u8) {
        GrayImage::from_pixel(6, 4, image::Luma([v]))
            .save(dir.join(name))
            .unwrap();
    }

    #[test]
    fn directory_in_name_order_cycles() {
        let dir = tempfile::tempdir().unwrap();
        write(dir.path(), "002.png", 20);
        write(dir.path(), "000.png", 0);
        write(dir.path(), "001.png", 10);
        std::fs::write(dir.path().join("notes.txt"), "not an image").unwrap();
        let mut s = FileSource::new(dir.path());
        s.open().unwrap();
        assert_eq!(s.files().len(), 3);
        let got: Vec<u8> = (0..5)
            .map(|_| s.grab(Duration::ZERO).unwrap().image.get_pixel(0, 0)[0])
            .collect();
        assert_eq!(got, [0, 10, 20, 0, 10]);
    }

    #[test]
    fn single_file_and_median() {
        let dir = tempfile::tempdir().unwrap();
        write(dir.path(), "a.png", 77);
        let mut s = FileSource::new(&dir.path().join("a.png"));
        let settings = CaptureSettings {
            frame_count: 3,
            interval: Duration::from_millis(10),
            settle_frames: 1,
            timeout: Duration::from_millis(10),
            retry: RetryPolicy {
                attempts: 1,
                backoff: Duration::ZERO,
                max_backoff: Duration::ZERO,
            },
        };
        let cap = capture(&mut s, &settings, &NoWait).unwrap();
        assert_eq!(cap.frames.len(), 3);
        assert_eq!(cap.median, GrayImage::from_pixel(6, 4, image::Luma([77])));
    }

    #[test]
    fn missing_empty_and_corrupt() {
        let dir = tempfile::tempdir().unwrap();
        let e = FileSource::new(&dir.path().join("nope"))
            .open()
            .unwrap_err();
        assert_eq!(e.fault, Fault::Absent);
        assert!(
            e.detail.contains("No such file or directory"),
            "{}",
            e.detail
        );

        let e = FileSource::new(dir.path()).open().unwrap_err();
        assert_eq!(e.fault, Fault::Absent);
        assert!(e.detail.contains("no png/jpg"), "{}", e.detail);

        std::fs::write(dir.path().join("bad.png"), b"\x89PNG\r\n\x1a\n truncated").unwrap();
        let mut s = FileSource::new(dir.path());
        s.open().unwrap();
        let e = s.grab(Duration::ZERO).unwrap_err();
        assert_eq!(e.fault, Fault::Corrupt);
        assert!(e.detail.contains("bad.png"), "{}", e.detail);
    }
}
