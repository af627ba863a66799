//! GigE Vision / USB3 Vision source through Aravis (cargo feature `aravis`, the `aravis` crate
//! over Debian's libaravis-0.8). Mono8, Mono16 and 8-bit Bayer frames become gray via
//! [`super::convert`]; region, exposure and gain come from the config.

use super::convert::{self, BayerPattern, Geometry};
use super::{Fault, Frame, FrameSource, GrabError};
use crate::config::CameraConfig;
use crate::error::{Error, Result};
use aravis::prelude::*;
use aravis::{AcquisitionMode, Auto, Buffer, BufferStatus, Camera, PixelFormat, Stream};
use image::GrayImage;
use std::time::{Duration, SystemTime};

/// Buffers queued on the stream: enough to ride out a slow conversion, few enough that a
/// returned frame is recent.
const BUFFERS: usize = 4;

/// The GenICam pixel formats this source converts, with their config names.
const FORMATS: [(&str, PixelFormat); 6] = [
    ("Mono8", PixelFormat::MONO_8),
    ("Mono16", PixelFormat::MONO_16),
    ("BayerRG8", PixelFormat::BAYER_RG_8),
    ("BayerBG8", PixelFormat::BAYER_BG_8),
    ("BayerGR8", PixelFormat::BAYER_GR_8),
    ("BayerGB8", PixelFormat::BAYER_GB_8),
];

/// Camera settings applied at open; `None` leaves the camera's own setting.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct AravisSettings {
    /// GenICam pixel format name (`Mono8`, `Mono16`, `BayerRG8`, …).
    pub pixel_format: Option<String>,
    /// Sensor region `[x, y, width, height]`.
    pub region: Option<[u32; 4]>,
    /// Exposure time, µs (switches auto-exposure off).
    pub exposure_us: Option<f64>,
    /// Gain, dB (switches auto-gain off).
    pub gain_db: Option<f64>,
}

/// Convert one GenICam buffer to gray. `x_padding` is the bytes after each row.
pub(crate) fn genicam_to_gray(
    format: PixelFormat,
    width: u32,
    height: u32,
    x_padding: usize,
    data: &[u8],
) -> Result<GrayImage, GrabError> {
    let bayer = |p| {
        convert::bayer8(
            Geometry::packed(width, height, 1).padded(x_padding),
            data,
            p,
        )
    };
    let image = match format {
        PixelFormat::MONO_8 => {
            convert::gray8(Geometry::packed(width, height, 1).padded(x_padding), data)
        }
        PixelFormat::MONO_16 => {
            convert::gray16le(Geometry::packed(width, height, 2).padded(x_padding), data)
        }
        PixelFormat::BAYER_RG_8 => bayer(BayerPattern::Rggb),
        PixelFormat::BAYER_BG_8 => bayer(BayerPattern::Bggr),
        PixelFormat::BAYER_GR_8 => bayer(BayerPattern::Grbg),
        PixelFormat::BAYER_GB_8 => bayer(BayerPattern::Gbrg),
        other => {
            return Err(GrabError::new(
                Fault::Unsupported,
                format!(
                    "pixel format 0x{:08x} is not one of {}",
                    other.raw(),
                    FORMATS.map(|(n, _)| n).join(", ")
                ),
            ))
        }
    };
    Ok(image?)
}

/// An Aravis camera (GigE Vision or USB3 Vision).
pub struct AravisSource {
    id: Option<String>,
    name: String,
    settings: AravisSettings,
    camera: Option<Camera>,
    stream: Option<Stream>,
}

impl AravisSource {
    /// A source for camera `id` (an Aravis device id such as `Basler-21234567`, or a GigE
    /// camera's IP address; `None` = the first camera found).
    pub fn new(id: Option<&str>, settings: AravisSettings) -> AravisSource {
        AravisSource {
            id: id.map(str::to_string),
            name: format!("aravis:{}", id.unwrap_or("<first camera>")),
            settings,
            camera: None,
            stream: None,
        }
    }

    /// From the `[camera]` table (`device`, `pixel-format`, `region`, `exposure-us`,
    /// `gain-db`); an empty `device` means the first camera found.
    pub(crate) fn from_config(c: &CameraConfig) -> Result<AravisSource> {
        if let Some(f) = &c.pixel_format {
            if !FORMATS.iter().any(|(n, _)| n == f) {
                return Err(Error::FrameSource(format!(
                    "[camera] pixel-format = \"{f}\" is not one of {}",
                    FORMATS.map(|(n, _)| n).join(", ")
                )));
            }
        }
        let id = c.device.as_deref().filter(|d| !d.is_empty());
        Ok(AravisSource::new(
            id,
            AravisSettings {
                pixel_format: c.pixel_format.clone(),
                region: c.region,
                exposure_us: c.exposure_us,
                gain_db: c.gain_db,
            },
        ))
    }

    /// Apply the settings; a refused setting is [`Fault::Unsupported`] naming the feature.
    fn configure(&self, cam: &Camera) -> Result<(), GrabError> {
        let refused = |what: String, e: aravis::glib::Error| {
            GrabError::new(Fault::Unsupported, format!("{what}: {e}"))
        };
        let s = &self.settings;
        if let Some(name) = &s.pixel_format {
            let (_, f) = FORMATS.iter().find(|(n, _)| n == name).ok_or_else(|| {
                GrabError::new(Fault::Unsupported, format!("pixel format {name}"))
            })?;
            cam.set_pixel_format(*f)
                .map_err(|e| refused(format!("pixel format {name}"), e))?;
        }
        if let Some([x, y, w, h]) = s.region {
            let i = |v: u32| i32::try_from(v).unwrap_or(i32::MAX);
            cam.set_region(i(x), i(y), i(w), i(h))
                .map_err(|e| refused(format!("region [{x}, {y}, {w}, {h}]"), e))?;
            // Cameras round regions to their increments: insist on what was configured,
            // because the intrinsics were calibrated for it.
            let got = cam
                .region()
                .map_err(|e| refused("reading back the region".into(), e))?;
            if got != (i(x), i(y), i(w), i(h)) {
                return Err(GrabError::new(
                    Fault::Unsupported,
                    format!("region [{x}, {y}, {w}, {h}] was adjusted by the camera to {got:?}"),
                ));
            }
        }
        if let Some(us) = s.exposure_us {
            // Not every camera has auto-exposure; only a refused manual value is an error.
            let _ = cam.set_exposure_time_auto(Auto::Off);
            cam.set_exposure_time(us)
                .map_err(|e| refused(format!("exposure {us} us"), e))?;
        }
        if let Some(db) = s.gain_db {
            let _ = cam.set_gain_auto(Auto::Off);
            cam.set_gain(db)
                .map_err(|e| refused(format!("gain {db} dB"), e))?;
        }
        cam.set_acquisition_mode(AcquisitionMode::Continuous)
            .map_err(|e| refused("continuous acquisition".into(), e))?;
        Ok(())
    }
}

/// Aravis reports "not found" as a plain error; everything at open time that is not a refused
/// setting means the camera cannot be reached.
fn absent(e: aravis::glib::Error) -> GrabError {
    GrabError::new(Fault::Absent, e.to_string())
}

impl FrameSource for AravisSource {
    fn device(&self) -> &str {
        &self.name
    }

    fn open(&mut self) -> Result<(), GrabError> {
        self.close();
        let cam = Camera::new(self.id.as_deref()).map_err(absent)?;
        self.configure(&cam)?;
        if cam.is_gv_device() {
            // Largest packet the path allows; failure just keeps the default size.
            let _ = cam.gv_auto_packet_size();
        }
        let payload = cam.payload().map_err(absent)? as usize;
        let stream = cam.create_stream().map_err(absent)?;
        for _ in 0..BUFFERS {
            stream.push_buffer(Buffer::new_allocate(payload));
        }
        cam.start_acquisition().map_err(absent)?;
        self.camera = Some(cam);
        self.stream = Some(stream);
        Ok(())
    }

    fn grab(&mut self, timeout: Duration) -> Result<Frame, GrabError> {
        let stream = self
            .stream
            .as_ref()
            .ok_or_else(|| GrabError::new(Fault::Io, "grab before open"))?;
        // Frames completed while nobody was grabbing (the burst sleeps between frames) are
        // stale, and once every buffer is full Aravis drops new frames: requeue them all, so
        // the frame returned is the next one to complete — at most one frame period old.
        for _ in 0..2 * BUFFERS {
            match stream.try_pop_buffer() {
                Some(stale) => stream.push_buffer(stale),
                None => break,
            }
        }
        let micros = u64::try_from(timeout.as_micros()).unwrap_or(u64::MAX);
        let buffer = stream.timeout_pop_buffer(micros).ok_or_else(|| {
            GrabError::new(
                Fault::Timeout,
                format!("no frame within {} ms", timeout.as_millis()),
            )
        })?;
        let result = frame_from_buffer(&buffer);
        // Requeue whatever happened, so the ring never runs dry.
        stream.push_buffer(buffer);
        result
    }

    fn close(&mut self) {
        if let Some(cam) = &self.camera {
            let _ = cam.stop_acquisition();
        }
        self.stream = None;
        self.camera = None;
    }
}

fn frame_from_buffer(buffer: &Buffer) -> Result<Frame, GrabError> {
    let status = buffer.status();
    if status != BufferStatus::Success {
        let fault = match status {
            BufferStatus::Timeout => Fault::Timeout,
            BufferStatus::SizeMismatch => Fault::Short,
            _ => Fault::Corrupt,
        };
        return Err(GrabError::new(fault, format!("buffer status {status:?}")));
    }
    let (w, h) = (buffer.image_width(), buffer.image_height());
    let (w, h) = (
        u32::try_from(w).map_err(|_| GrabError::new(Fault::Corrupt, format!("width {w}")))?,
        u32::try_from(h).map_err(|_| GrabError::new(Fault::Corrupt, format!("height {h}")))?,
    );
    let (x_padding, _) = buffer.image_padding();
    let data = buffer.image_data();
    let image = genicam_to_gray(
        buffer.image_pixel_format(),
        w,
        h,
        usize::try_from(x_padding).unwrap_or(0),
        &data,
    )?;
    Ok(Frame {
        image,
        // Host time at which Aravis completed the frame, ns since the Unix epoch.
        timestamp: SystemTime::UNIX_EPOCH + Duration::from_nanos(buffer.system_timestamp()),
        sequence: buffer.frame_id(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn genicam_formats_convert() {
        let img = GrayImage::from_fn(8, 4, |x, y| image::Luma([(x * 20 + y * 3) as u8]));
        // Mono8 with 3 bytes of row padding.
        let mut mono8 = Vec::new();
        for row in img.rows() {
            mono8.extend(row.map(|p| p[0]));
            mono8.extend([0xEE; 3]);
        }
        assert_eq!(
            genicam_to_gray(PixelFormat::MONO_8, 8, 4, 3, &mono8).unwrap(),
            img
        );
        let mono16: Vec<u8> = img.pixels().flat_map(|p| [0x11, p[0]]).collect();
        assert_eq!(
            genicam_to_gray(PixelFormat::MONO_16, 8, 4, 0, &mono16).unwrap(),
            img
        );
        let e = genicam_to_gray(PixelFormat::RGB_8_PACKED, 8, 4, 0, &[0; 96]).unwrap_err();
        assert_eq!(e.fault, Fault::Unsupported);
        assert!(e.detail.contains("Mono8, Mono16, BayerRG8"), "{}", e.detail);
        let e = genicam_to_gray(PixelFormat::MONO_8, 8, 4, 0, &[0; 31]).unwrap_err();
        assert_eq!(e.fault, Fault::Short);
    }
}
