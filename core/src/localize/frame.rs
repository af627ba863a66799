//! What the localizer looks at: a [`Frame`] (the camera, its gray image and the image circle's
//! mask, consistent by construction) and the [`MapLayers`] the image is matched against.

use crate::camera::{Camera, CameraModel};
use crate::error::{Error, Result};
use crate::map::Raster;
use crate::stage::StageName;
use std::sync::OnceLock;

/// One (temporally median-filtered) gray frame with the camera that took it. The image has the
/// camera's size (checked by [`Frame::new`]); the valid-pixel mask is computed once, when first
/// asked for (initialization needs none, the MI stages do).
#[derive(Debug)]
pub struct Frame<'a> {
    camera: &'a Camera,
    gray: &'a [u8],
    mask: OnceLock<Vec<u8>>,
}

impl<'a> Frame<'a> {
    /// The frame `gray` (row-major, 8-bit) taken by `camera`; a `capture` error when its size is
    /// not the camera's.
    pub fn new(camera: &'a Camera, gray: &'a [u8]) -> Result<Self> {
        let (w, h) = (camera.width() as usize, camera.height() as usize);
        if gray.len() != w * h {
            return Err(Error::stage(
                StageName::Capture,
                format!("frame has {} pixels, camera expects {w}×{h}", gray.len()),
            ));
        }
        Ok(Frame {
            camera,
            gray,
            mask: OnceLock::new(),
        })
    }

    /// The camera.
    pub fn camera(&self) -> &'a Camera {
        self.camera
    }

    /// The gray image, row-major at the camera's size.
    pub fn gray(&self) -> &'a [u8] {
        self.gray
    }

    /// The camera's valid-pixel mask (its image circle), 255 inside, 0 outside.
    pub(crate) fn mask(&self) -> &[u8] {
        self.mask.get_or_init(|| self.camera.valid_mask())
    }
}

/// The map layers the image is matched against: the satellite orthoimage and the height layer
/// (same tile, the map's CRS).
#[derive(Debug, Clone, Copy)]
pub struct MapLayers<'a> {
    /// Satellite RGB.
    pub satellite: &'a Raster<[u8; 3]>,
    /// Ground heights, metres.
    pub heights: &'a Raster<f32>,
}
