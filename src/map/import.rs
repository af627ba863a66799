//! Building a tile from external rasters (I/O shell behind `infraloc tile import`).
//!
//! A source raster is either a GeoTIFF (its georeference tags are used, and its EPSG code must be
//! the `--crs` given) or a PNG/TIFF with a world file (`.pgw`/`.tfw`/`.wld`: six lines A D B E C F,
//! where (C, F) is the *centre* of the upper-left pixel; the CRS is the `--crs` given). A world
//! file is found beside the image when not named explicitly.

use super::cache::{parse_control_points, Provenance};
use super::geotiff::{self, Image, Pixels};
use super::{Crs, GeoGrid, MapError, Tile};
use crate::error::{Error, Result};
use crate::geo;
use std::path::{Path, PathBuf};

/// World-file extensions tried beside an image without georeference, in this order.
pub(crate) const WORLD_EXTENSIONS: [&str; 5] = ["pgw", "pngw", "tfw", "tifw", "wld"];
/// Relative tolerance for "square pixels" in a world file.
const SQUARE_REL_TOL: f64 = 1e-9;
/// TIFF magic numbers (little- and big-endian; classic and BigTIFF share the first two bytes).
const TIFF_MAGIC: [&[u8]; 2] = [b"II", b"MM"];

/// One source raster of a tile and, optionally, its world file.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Source<'a> {
    /// Image file (GeoTIFF, TIFF or PNG).
    pub image: &'a Path,
    /// World file; `None` = use GeoTIFF tags, else look for a sibling world file.
    pub world: Option<&'a Path>,
}

/// Parse a world file into the PixelIsArea grid of a `width`×`height` image.
///
/// Lines: A (x pixel size), D (rotation), B (rotation), E (y pixel size, negative), C, F (map
/// coordinates of the centre of the upper-left pixel). The grid corner is half a pixel out from
/// (C, F). Rotation terms must be 0 and pixels square.
pub(crate) fn parse_world_file(
    text: &str,
    path: &Path,
    crs: Crs,
    width: usize,
    height: usize,
) -> Result<GeoGrid> {
    let vals: Vec<(usize, &str)> = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty())
        .collect();
    if vals.len() != 6 {
        return Err(Error::input(
            path,
            format!(
                "world file has {} values, expected 6 lines A D B E C F",
                vals.len()
            ),
        ));
    }
    let mut v = [0.0; 6];
    for (k, (line, s)) in vals.iter().enumerate() {
        v[k] = s
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| Error::input(path, format!("line {line}: {s:?} is not a number")))?;
    }
    let [a, d, b, e, c, f] = v;
    if d != 0.0 || b != 0.0 {
        return Err(Error::input(
            path,
            format!("rotation terms D={d}, B={b} are not 0: rotated rasters are not supported"),
        ));
    }
    if !(a > 0.0) || !(e < 0.0) {
        return Err(Error::input(
            path,
            format!("pixel size A={a}, E={e}: need A > 0 and E < 0 (north-up)"),
        ));
    }
    if (a + e).abs() > SQUARE_REL_TOL * a {
        return Err(Error::input(
            path,
            format!("pixels are not square (A={a}, E={e}); resample to square pixels"),
        ));
    }
    Ok(GeoGrid {
        crs,
        x0: c - 0.5 * a,
        y0: f + 0.5 * a,
        res: a,
        width,
        height,
    })
}

/// The world file beside `image`, if any (`name.pgw`, `name.pngw`, `name.tfw`, …).
pub(crate) fn sibling_world_file(image: &Path) -> Option<PathBuf> {
    WORLD_EXTENSIONS
        .iter()
        .map(|ext| image.with_extension(ext))
        .find(|p| p.is_file())
}

/// Decode a PNG (via `image`) or TIFF (via [`geotiff::read_image`]) by its content.
fn decode(path: &Path) -> Result<Image> {
    let mut magic = [0u8; 2];
    {
        use std::io::Read;
        let mut f = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
        f.read_exact(&mut magic)
            .map_err(|_| Error::input(path, "file too short to be an image"))?;
    }
    if TIFF_MAGIC.contains(&&magic[..]) {
        return geotiff::read_image(path);
    }
    let img = image::ImageReader::open(path)
        .map_err(|e| Error::io(path, e))?
        .with_guessed_format()
        .map_err(|e| Error::io(path, e))?
        .decode()
        .map_err(|e| Error::input(path, format!("not a readable image: {e}")))?;
    let (width, height) = (img.width() as usize, img.height() as usize);
    let opaque = |all_opaque: bool| -> Result<()> {
        if all_opaque {
            Ok(())
        } else {
            Err(Error::input(
                path,
                "has transparent pixels; flatten the alpha channel first",
            ))
        }
    };
    let pixels = match img {
        image::DynamicImage::ImageLuma8(b) => Pixels::Gray8(b.into_raw()),
        image::DynamicImage::ImageRgb8(b) => Pixels::Rgb8(b.into_raw()),
        image::DynamicImage::ImageLumaA8(b) => {
            opaque(b.pixels().all(|p| p.0[1] == u8::MAX))?;
            Pixels::Gray8(b.pixels().map(|p| p.0[0]).collect())
        }
        image::DynamicImage::ImageRgba8(b) => {
            opaque(b.pixels().all(|p| p.0[3] == u8::MAX))?;
            Pixels::Rgb8(b.pixels().flat_map(|p| [p.0[0], p.0[1], p.0[2]]).collect())
        }
        other => {
            return Err(Error::input(
                path,
                format!(
                    "unsupported pixel type {:?} (supported: 8-bit gray/RGB; heights need an f32 TIFF, \
                     e.g. gdal_translate -ot Float32)",
                    other.color()
                ),
            ))
        }
    };
    Ok(Image {
        width,
        height,
        pixels,
        grid: None,
        nodata: None,
    })
}

/// Read one source raster and its georeference in `crs`. Returns the image, its grid and a
/// description of where the georeference came from (for provenance).
pub(crate) fn read_source(
    src: Source<'_>,
    crs: Crs,
    flag: &str,
) -> Result<(Image, GeoGrid, String)> {
    let img = decode(src.image)?;
    if let Some(g) = img.grid {
        if let Some(w) = src.world {
            return Err(MapError::WorldWithGeoTiff {
                image: src.image.to_path_buf(),
                flag: flag.to_string(),
                world: w.to_path_buf(),
            }
            .into());
        }
        if g.crs != crs {
            return Err(Error::input(
                src.image,
                format!("GeoTIFF CRS is {} but --crs is {crs}", g.crs),
            ));
        }
        let what = format!("{} (GeoTIFF)", src.image.display());
        return Ok((img, g, what));
    }
    let world = match src.world {
        Some(w) => w.to_path_buf(),
        None => sibling_world_file(src.image).ok_or_else(|| {
            Error::input(
                src.image,
                format!(
                    "no georeference: not a GeoTIFF and no world file beside it (.{}); give {flag}-world",
                    WORLD_EXTENSIONS.join("/.")
                ),
            )
        })?,
    };
    let text = std::fs::read_to_string(&world).map_err(|e| Error::io(&world, e))?;
    let grid = parse_world_file(&text, &world, crs, img.width, img.height)?;
    let what = format!("{} + world file {}", src.image.display(), world.display());
    Ok((img, grid, what))
}

/// Read an image and its georeference in any CRS the geodesy knows: a GeoTIFF's own, else a world
/// file's (taken to be in `crs`). Returns the image, its grid and where the georeference came from.
pub(crate) fn read_source_any_crs(
    image: &Path,
    crs: Crs,
    flag: &str,
) -> Result<(Image, GeoGrid, String)> {
    let img = decode(image)?;
    match img.grid {
        Some(g) => Ok((img, g, format!("{} (GeoTIFF)", image.display()))),
        None => read_source(Source { image, world: None }, crs, flag),
    }
}

/// Build a tile from its sources. `crs` must be a WGS84 UTM EPSG code; every GeoTIFF source must
/// be in it. Reflectivity and height must share one grid. Returns the tile and its provenance.
pub(crate) fn import_tile(
    id: &str,
    crs: Crs,
    satellite: Source<'_>,
    reflectivity: Source<'_>,
    height: Source<'_>,
    control_points: Option<&Path>,
) -> Result<(Tile, Provenance)> {
    geo::check_crs(crs).map_err(|source| MapError::Flag {
        flag: "--crs",
        source,
    })?;
    let (si, sg, sd) = read_source(satellite, crs, "--satellite")?;
    let (ri, rg, rd) = read_source(reflectivity, crs, "--reflectivity")?;
    let (hi, hg, hd) = read_source(height, crs, "--height")?;
    let mut sources = vec![
        format!("satellite: {sd}"),
        format!("reflectivity: {rd}"),
        format!("height: {hd}"),
    ];
    let sat = geotiff::raster_rgb8(si, sg, satellite.image)?;
    let refl = geotiff::raster_gray8(ri, rg, reflectivity.image)?;
    let hgt = geotiff::raster_f32(hi, hg, height.image)?;
    if refl.grid != hgt.grid {
        let d = |g: &GeoGrid| {
            format!(
                "{}x{} at ({}, {}) res {}",
                g.width, g.height, g.x0, g.y0, g.res
            )
        };
        return Err(Error::input(
            height.image,
            format!(
                "height grid {} differs from reflectivity grid {} ({}); they must share one grid",
                d(&hgt.grid),
                d(&refl.grid),
                reflectivity.image.display()
            ),
        ));
    }
    let cps = match control_points {
        None => Vec::new(),
        Some(p) => {
            let text = std::fs::read_to_string(p).map_err(|e| Error::io(p, e))?;
            sources.push(format!("control points: {}", p.display()));
            parse_control_points(&text, p)?
        }
    };
    let tile = Tile {
        id: id.to_string(),
        satellite: Some(sat),
        reflectivity: refl,
        height: hgt,
        control_points: cps,
    };
    let provenance = Provenance {
        sources,
        ..Provenance::default()
    };
    Ok((tile, provenance))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn world_file_centre_to_corner() {
        let p = Path::new("a.pgw");
        let g = parse_world_file(
            "0.5\n0\n0\n-0.5\n1000.25\n2000.75\n",
            p,
            Crs::Epsg(32617),
            4,
            3,
        )
        .unwrap();
        assert_eq!((g.x0, g.y0, g.res), (1000.0, 2001.0, 0.5));
        // The centre of pixel (0, 0) is (C, F) again.
        assert_eq!(g.pixel_center(0, 0), (1000.25, 2000.75));
        let e = parse_world_file("0.5\n0.1\n0\n-0.5\n0\n0\n", p, Crs::Epsg(32617), 1, 1)
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("a.pgw: rotation terms"), "{e}");
        let e = parse_world_file("0.5\n0\n0\n-0.4\n0\n0\n", p, Crs::Epsg(32617), 1, 1)
            .unwrap_err()
            .to_string();
        assert!(e.contains("not square"), "{e}");
        let e = parse_world_file("0.5\n0\nx\n-0.5\n0\n0\n", p, Crs::Epsg(32617), 1, 1)
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 3"), "{e}");
    }
}
