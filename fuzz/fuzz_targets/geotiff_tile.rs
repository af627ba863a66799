//! Arbitrary bytes as a tile layer's GeoTIFF, through the reader every tile load uses
//! (`map::geotiff::decode_image`: TIFF decoding, the parallel chunk path, the georeference and
//! GeoKey tags, GDAL_NODATA): no panic, and an accepted image is consistent — as many samples as
//! its size says, and a georeference (if any) on the image's own size with a finite origin and a
//! positive, finite pixel size.
#![no_main]

use infraloc::map::geotiff::{decode_image, Pixels};
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(img) = decode_image(data, Path::new("fuzz.tif")) else {
        return;
    };
    let (n, per) = match &img.pixels {
        Pixels::Gray8(v) => (v.len(), 1),
        Pixels::Rgb8(v) => (v.len(), 3),
        Pixels::F32(v) => (v.len(), 1),
    };
    assert_eq!(n, img.width * img.height * per, "{}×{}", img.width, img.height);
    if let Some(g) = img.grid {
        assert_eq!((g.width, g.height), (img.width, img.height));
        assert!(g.x0.is_finite() && g.y0.is_finite(), "{g:?}");
        assert!(g.res.is_finite() && g.res > 0.0, "{g:?}");
    }
});
