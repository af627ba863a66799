//! V4L2 source (`/dev/videoN`, cargo feature `v4l`): memory-mapped streaming of GREY, Y16,
//! YUYV or MJPG frames, converted to gray by [`super::convert`].

use super::convert::{self, ConvertError, Geometry};
use super::{Fault, Frame, FrameSource, GrabError};
use crate::config::CameraConfig;
use crate::error::{Error, Result};
use image::GrayImage;
use std::time::{Duration, Instant, SystemTime};
use v4l::buffer::{Flags, Type};
use v4l::io::mmap::Stream;
use v4l::io::traits::CaptureStream;
use v4l::video::Capture;
use v4l::{Device, FourCC};

/// Driver buffers in the mmap ring: enough that a slow conversion does not drop frames, few
/// enough that a returned frame is at most this many frames old.
const BUFFERS: u32 = 4;
/// A dequeue that returns faster than this found its buffer already filled (a frame older than
/// the call); a camera's frame period is far longer.
const READY_WITHOUT_WAITING: Duration = Duration::from_millis(2);

/// The V4L2 pixel formats this source converts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum V4l2Format {
    /// 8-bit gray.
    Grey,
    /// 16-bit gray, little-endian.
    Y16,
    /// YUV 4:2:2 packed, Y0 U Y1 V.
    Yuyv,
    /// Motion-JPEG.
    Mjpeg,
}

impl V4l2Format {
    /// All of them, in preference order (uncompressed gray first).
    pub(crate) const ALL: [V4l2Format; 4] = [
        V4l2Format::Grey,
        V4l2Format::Y16,
        V4l2Format::Yuyv,
        V4l2Format::Mjpeg,
    ];

    /// The V4L2 four-character code.
    pub(crate) fn fourcc(self) -> [u8; 4] {
        match self {
            V4l2Format::Grey => *b"GREY",
            V4l2Format::Y16 => *b"Y16 ",
            V4l2Format::Yuyv => *b"YUYV",
            V4l2Format::Mjpeg => *b"MJPG",
        }
    }

    /// From a config name (`GREY`, `Y16`, `YUYV`, `MJPG`) or a driver four-character code.
    pub(crate) fn parse(name: &str) -> Option<V4l2Format> {
        V4l2Format::ALL
            .into_iter()
            .find(|f| f.fourcc().trim_ascii_end() == name.trim_end().as_bytes())
    }

    /// Convert one driver buffer of `width`×`height` with `stride` bytes per row (ignored for
    /// MJPEG) to gray.
    pub(crate) fn to_gray(
        self,
        width: u32,
        height: u32,
        stride: usize,
        buf: &[u8],
    ) -> Result<GrayImage, ConvertError> {
        // Drivers may report stride 0 for packed formats; then rows are tightly packed.
        let bpp = match self {
            V4l2Format::Grey => 1,
            V4l2Format::Y16 | V4l2Format::Yuyv => 2,
            V4l2Format::Mjpeg => return convert::mjpeg(buf, Some((width, height))),
        };
        let g = Geometry {
            width,
            height,
            stride: if stride == 0 {
                width as usize * bpp
            } else {
                stride
            },
        };
        match self {
            V4l2Format::Grey => convert::gray8(g, buf),
            V4l2Format::Y16 => convert::gray16le(g, buf),
            _ => convert::yuyv(g, buf),
        }
    }
}

/// A V4L2 capture device.
pub(crate) struct V4l2Source {
    path: String,
    want_format: Option<V4l2Format>,
    want_size: Option<[u32; 2]>,
    dev: Option<Device>,
    stream: Option<Stream<'static>>,
    active: Option<(V4l2Format, u32, u32, usize)>,
}

impl V4l2Source {
    /// A source for device `path`, optionally requesting a format and size.
    pub(crate) fn new(
        path: &str,
        format: Option<V4l2Format>,
        size: Option<[u32; 2]>,
    ) -> V4l2Source {
        V4l2Source {
            path: path.to_string(),
            want_format: format,
            want_size: size,
            dev: None,
            stream: None,
            active: None,
        }
    }

    /// From the `[camera]` table (`device`, `pixel-format`, `resolution`).
    pub(crate) fn from_config(c: &CameraConfig) -> Result<V4l2Source> {
        let dev = c
            .device
            .as_deref()
            .ok_or_else(|| Error::FrameSource("[camera] source = \"v4l2\" needs device".into()))?;
        let format = match c.pixel_format.as_deref() {
            None => None,
            Some(name) => Some(V4l2Format::parse(name).ok_or_else(|| {
                Error::FrameSource(format!(
                    "[camera] pixel-format = \"{name}\" is not one of GREY, Y16, YUYV, MJPG"
                ))
            })?),
        };
        Ok(V4l2Source::new(dev, format, c.resolution))
    }

    fn configure(&self, dev: &Device) -> Result<(V4l2Format, u32, u32, usize), GrabError> {
        let io = |e: std::io::Error| GrabError::from_io(&e);
        let mut fmt = dev.format().map_err(io)?;
        if self.want_format.is_some() || self.want_size.is_some() {
            if let Some(f) = self.want_format {
                fmt.fourcc = FourCC::new(&f.fourcc());
            }
            if let Some([w, h]) = self.want_size {
                fmt.width = w;
                fmt.height = h;
            }
            // Drivers adjust what they cannot do; check what we actually got below.
            fmt = dev.set_format(&fmt).map_err(io)?;
        }
        let fourcc = fmt.fourcc.repr;
        let got = V4l2Format::ALL
            .into_iter()
            .find(|f| f.fourcc() == fourcc)
            .ok_or_else(|| {
                GrabError::new(
                    Fault::Unsupported,
                    format!(
                        "pixel format {} is not one of GREY, Y16, YUYV, MJPG",
                        String::from_utf8_lossy(&fourcc)
                    ),
                )
            })?;
        if let Some(want) = self.want_format.filter(|w| *w != got) {
            return Err(GrabError::new(
                Fault::Unsupported,
                format!(
                    "driver refused pixel format {}, offers {}",
                    String::from_utf8_lossy(&want.fourcc()),
                    String::from_utf8_lossy(&fourcc)
                ),
            ));
        }
        if let Some([w, h]) = self.want_size.filter(|s| *s != [fmt.width, fmt.height]) {
            return Err(GrabError::new(
                Fault::Unsupported,
                format!(
                    "driver refused {w}x{h}, offers {}x{}",
                    fmt.width, fmt.height
                ),
            ));
        }
        Ok((got, fmt.width, fmt.height, fmt.stride as usize))
    }
}

impl FrameSource for V4l2Source {
    fn device(&self) -> &str {
        &self.path
    }

    fn open(&mut self) -> Result<(), GrabError> {
        self.close();
        let dev = Device::with_path(&self.path).map_err(|e| GrabError::from_io(&e))?;
        let active = self.configure(&dev)?;
        let stream = Stream::with_buffers(&dev, Type::VideoCapture, BUFFERS)
            .map_err(|e| GrabError::from_io(&e))?;
        self.active = Some(active);
        self.stream = Some(stream);
        self.dev = Some(dev);
        Ok(())
    }

    fn grab(&mut self, timeout: Duration) -> Result<Frame, GrabError> {
        let (format, w, h, stride) = self
            .active
            .ok_or_else(|| GrabError::new(Fault::Io, "grab before open"))?;
        let stream = self
            .stream
            .as_mut()
            .ok_or_else(|| GrabError::new(Fault::Io, "grab before open"))?;
        stream.set_timeout(timeout);
        // The driver keeps filling queued buffers while the burst sleeps, then drops frames
        // once all are full, so the first buffers dequeued are old. A buffer that is ready
        // without waiting may be such a stale one: discard up to BUFFERS of them. After that
        // every buffer was refilled after this call began, so the frame returned is at most
        // one frame period old. (The v4l crate exposes buffers only through `next`, so the
        // drain cannot use a zero-timeout poll.)
        let mut discarded = 0;
        loop {
            let asked = Instant::now();
            let (buf, meta) = stream.next().map_err(|e| {
                if e.kind() == std::io::ErrorKind::TimedOut {
                    GrabError::new(
                        Fault::Timeout,
                        format!("no frame within {} ms", timeout.as_millis()),
                    )
                } else {
                    GrabError::from_io(&e)
                }
            })?;
            if asked.elapsed() < READY_WITHOUT_WAITING && discarded < BUFFERS {
                discarded += 1;
                continue;
            }
            if meta.flags.contains(Flags::ERROR) {
                return Err(GrabError::new(
                    Fault::Corrupt,
                    "driver flagged the frame as damaged (V4L2_BUF_FLAG_ERROR)",
                ));
            }
            let used = (meta.bytesused as usize).min(buf.len());
            let image = format.to_gray(w, h, stride, &buf[..used])?;
            return Ok(Frame {
                image,
                // The driver timestamp is CLOCK_MONOTONIC, which std cannot map to wall time;
                // dequeue time is within one poll wake-up of it.
                timestamp: SystemTime::now(),
                sequence: meta.sequence as u64,
            });
        }
    }

    fn close(&mut self) {
        // The stream unmaps and stops before the device handle closes.
        self.stream = None;
        self.dev = None;
        self.active = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::capture::{capture, CaptureSettings, Clock, RetryPolicy};

    #[test]
    fn format_names_round_trip() {
        for f in V4l2Format::ALL {
            let code = String::from_utf8(f.fourcc().to_vec()).unwrap();
            assert_eq!(V4l2Format::parse(&code), Some(f));
            assert_eq!(V4l2Format::parse(code.trim()), Some(f));
        }
        assert_eq!(V4l2Format::parse("RGB3"), None);
    }

    #[test]
    fn driver_buffers_convert() {
        // GREY with a 64-byte stride, Y16 and YUYV packed: the stride rules drivers use.
        let img = GrayImage::from_fn(40, 6, |x, y| image::Luma([(x * 5 + y * 31) as u8]));
        let mut grey = vec![0u8; 64 * 6];
        for (y, row) in img.rows().enumerate() {
            for (x, p) in row.enumerate() {
                grey[y * 64 + x] = p[0];
            }
        }
        assert_eq!(V4l2Format::Grey.to_gray(40, 6, 64, &grey).unwrap(), img);
        let y16: Vec<u8> = img.pixels().flat_map(|p| [0x5A, p[0]]).collect();
        assert_eq!(V4l2Format::Y16.to_gray(40, 6, 0, &y16).unwrap(), img);
        let yuyv: Vec<u8> = img.pixels().flat_map(|p| [p[0], 128]).collect();
        assert_eq!(V4l2Format::Yuyv.to_gray(40, 6, 80, &yuyv).unwrap(), img);
        // A frame cut short by the driver (bytesused) is a short frame.
        assert!(matches!(
            V4l2Format::Yuyv.to_gray(40, 6, 80, &yuyv[..400]),
            Err(ConvertError::Short { .. })
        ));
    }

    struct NoWait;
    impl Clock for NoWait {
        fn now(&self) -> Duration {
            Duration::ZERO
        }
        fn sleep(&self, _: Duration) {}
    }

    #[test]
    fn absent_device_is_a_clear_error_naming_it() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("video0");
        let path = path.to_str().unwrap();
        let mut src = V4l2Source::new(path, Some(V4l2Format::Grey), None);
        let e = src.open().unwrap_err();
        assert_eq!(e.fault, Fault::Absent);
        let settings = CaptureSettings {
            frame_count: 5,
            interval: Duration::from_secs(1),
            settle_frames: 5,
            timeout: Duration::from_secs(2),
            retry: RetryPolicy {
                attempts: 2,
                backoff: Duration::from_millis(500),
                max_backoff: Duration::from_secs(1),
            },
        };
        let e = capture(&mut src, &settings, &NoWait)
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            format!(
                "capture: camera {path}: No such file or directory (os error 2) \
                 [device absent; gave up after 2 attempts]"
            )
        );
    }

    #[test]
    fn a_non_video_device_is_not_taken_for_a_camera() {
        // /dev/null opens but answers no V4L2 ioctl: an I/O error, never a frame.
        let mut src = V4l2Source::new("/dev/null", None, None);
        let e = src.open().unwrap_err();
        assert_ne!(e.fault, Fault::Absent, "{e:?}");
    }
}
