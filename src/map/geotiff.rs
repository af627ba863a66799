//! GeoTIFF read/write (I/O shell) for the three tile layer kinds: u8 gray, u8 RGB and f32.
//!
//! Written files carry ModelPixelScale (33550) + ModelTiepoint (33922), a GeoKeyDirectory (34735)
//! with GTModelType = Projected, GTRasterType = PixelIsArea and ProjectedCSType = the EPSG code,
//! and GDAL_NODATA (42113). `tests/gdal_reads_tiles.rs` checks with `gdalinfo` that GDAL places them
//! exactly where [`GeoGrid`] says.
//!
//! Reading accepts ModelPixelScale + ModelTiepoint or a north-up ModelTransformation (34264), and
//! PixelIsPoint rasters (shifted by half a pixel to the PixelIsArea corner, as GDAL does). Every
//! problem — truncated or corrupt file, unsupported sample type, missing or rotated georeference,
//! a CRS that is not a projected EPSG CRS in metres — is an [`Error::Input`] naming the file.

use super::{Crs, GeoGrid, Raster};
use crate::error::{Error, Result};
use crate::geo;
use std::fs::File;
use std::io::{BufWriter, Cursor};
use std::path::Path;
use tiff::decoder::{ChunkType, Decoder, DecodingResult, Limits};
use tiff::encoder::{colortype, Compression, DeflateLevel, TiffEncoder};
use tiff::tags::Tag;
use tiff::ColorType;

/// GeoKey: GTModelTypeGeoKey.
const KEY_MODEL_TYPE: u16 = 1024;
/// GeoKey: GTRasterTypeGeoKey.
const KEY_RASTER_TYPE: u16 = 1025;
/// GeoKey: GeographicTypeGeoKey.
const KEY_GEOGRAPHIC_TYPE: u16 = 2048;
/// GeoKey: ProjectedCSTypeGeoKey.
const KEY_PROJECTED_CS_TYPE: u16 = 3072;
/// GeoKey: ProjLinearUnitsGeoKey.
const KEY_PROJ_LINEAR_UNITS: u16 = 3076;
/// GTModelType value: projected CRS.
const MODEL_TYPE_PROJECTED: u16 = 1;
/// GTModelType value: geographic CRS.
const MODEL_TYPE_GEOGRAPHIC: u16 = 2;
/// GTRasterType value: a pixel covers an area; the tiepoint is the pixel's outer corner.
const RASTER_PIXEL_IS_AREA: u16 = 1;
/// GTRasterType value: a pixel is a point sample; the tiepoint is the pixel centre.
const RASTER_PIXEL_IS_POINT: u16 = 2;
/// GeoKey value meaning "user-defined" (no EPSG code).
const USER_DEFINED: u16 = 32767;
/// EPSG unit code of the metre.
const UNIT_METRE: u16 = 9001;
/// GeoKeyDirectory header: KeyDirectoryVersion, KeyRevision, MinorRevision.
const GEOKEY_HEADER: [u16; 3] = [1, 1, 0];
/// Largest decoded image accepted, bytes: a 1 km tile at 5 cm/px in RGB, with room to spare.
/// Bounds memory use on corrupt headers that claim huge sizes.
const MAX_DECODE_BYTES: usize = 1 << 30;
/// Relative tolerance for "square pixels" and "north-up" checks on georeference tags.
const GEOREF_REL_TOL: f64 = 1e-9;

/// Pixel data of a GeoTIFF, by sample type.
#[derive(Debug, Clone, PartialEq)]
pub enum Pixels {
    /// One u8 band.
    Gray8(Vec<u8>),
    /// Three interleaved u8 bands, R G B.
    Rgb8(Vec<u8>),
    /// One f32 band.
    F32(Vec<f32>),
}

impl Pixels {
    fn kind(&self) -> &'static str {
        match self {
            Pixels::Gray8(_) => "u8 gray",
            Pixels::Rgb8(_) => "u8 RGB",
            Pixels::F32(_) => "f32",
        }
    }
}

/// A decoded TIFF image with its georeference (if it had one) and GDAL_NODATA (if present).
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Samples, row-major.
    pub pixels: Pixels,
    /// Georeference from the GeoTIFF tags; `None` for a plain TIFF.
    pub grid: Option<GeoGrid>,
    /// GDAL_NODATA as a number (NaN allowed).
    pub nodata: Option<f64>,
}

fn tiff_err<'a>(path: &'a Path, what: &str) -> impl Fn(tiff::TiffError) -> Error + 'a {
    let what = what.to_string();
    move |e| Error::input(path, format!("{what}: {e}"))
}

/// GDAL_NODATA text of a value: GDAL parses "nan" and plain decimals.
fn nodata_text(v: f64) -> String {
    if v.is_nan() {
        "nan".into()
    } else {
        format!("{v}")
    }
}

fn geo_keys(grid: &GeoGrid, path: &Path) -> Result<Vec<u16>> {
    let code = match grid.crs {
        Crs::Epsg(c) => c,
        Crs::Local => {
            return Err(Error::input(
                path,
                "cannot write a GeoTIFF in the LOCAL frame: it has no EPSG code",
            ))
        }
    };
    geo::check_crs(grid.crs).map_err(|e| Error::input(path, e.to_string()))?;
    let code = u16::try_from(code)
        .map_err(|_| Error::input(path, format!("EPSG:{code} does not fit a GeoKey")))?;
    let keys: [[u16; 4]; 4] = [
        [KEY_MODEL_TYPE, 0, 1, MODEL_TYPE_PROJECTED],
        [KEY_RASTER_TYPE, 0, 1, RASTER_PIXEL_IS_AREA],
        [KEY_PROJECTED_CS_TYPE, 0, 1, code],
        [KEY_PROJ_LINEAR_UNITS, 0, 1, UNIT_METRE],
    ];
    let mut v = GEOKEY_HEADER.to_vec();
    v.push(keys.len() as u16);
    v.extend(keys.iter().flatten());
    Ok(v)
}

fn check_grid(grid: &GeoGrid, n: usize, path: &Path) -> Result<(u32, u32)> {
    if grid.width == 0 || grid.height == 0 || grid.len() != n {
        return Err(Error::input(
            path,
            format!(
                "raster is {}x{} but holds {n} samples",
                grid.width, grid.height
            ),
        ));
    }
    if !(grid.res > 0.0) || !grid.x0.is_finite() || !grid.y0.is_finite() {
        return Err(Error::input(
            path,
            format!(
                "invalid grid: x0={} y0={} res={}",
                grid.x0, grid.y0, grid.res
            ),
        ));
    }
    let w = u32::try_from(grid.width).map_err(|_| Error::input(path, "raster too wide"))?;
    let h = u32::try_from(grid.height).map_err(|_| Error::input(path, "raster too tall"))?;
    Ok((w, h))
}

/// Write one georeferenced image; `C` selects the TIFF sample layout.
fn write_image<C>(path: &Path, grid: &GeoGrid, data: &[C::Inner], nodata: Option<f64>) -> Result<()>
where
    C: colortype::ColorType,
    [C::Inner]: tiff::encoder::TiffValue,
{
    let samples_per_pixel = C::BITS_PER_SAMPLE.len();
    let (w, h) = check_grid(grid, data.len() / samples_per_pixel.max(1), path)?;
    let keys = geo_keys(grid, path)?;
    let file = File::create(path).map_err(|e| Error::io(path, e))?;
    let werr = tiff_err(path, "writing GeoTIFF");
    let mut enc = TiffEncoder::new(BufWriter::new(file))
        .map_err(&werr)?
        .with_compression(Compression::Deflate(DeflateLevel::Balanced));
    let mut img = enc.new_image::<C>(w, h).map_err(&werr)?;
    let d = img.encoder();
    d.write_tag(Tag::ModelPixelScaleTag, &[grid.res, grid.res, 0.0][..])
        .map_err(&werr)?;
    d.write_tag(
        Tag::ModelTiepointTag,
        &[0.0, 0.0, 0.0, grid.x0, grid.y0, 0.0][..],
    )
    .map_err(&werr)?;
    d.write_tag(Tag::GeoKeyDirectoryTag, &keys[..])
        .map_err(&werr)?;
    if let Some(v) = nodata {
        d.write_tag(Tag::GdalNodata, nodata_text(v).as_str())
            .map_err(&werr)?;
    }
    img.write_data(data).map_err(&werr)?;
    drop(enc);
    Ok(())
}

/// Write a u8 gray GeoTIFF (GDAL_NODATA from `r.nodata`).
pub(crate) fn write_gray8(path: &Path, r: &Raster<u8>) -> Result<()> {
    write_image::<colortype::Gray8>(path, &r.grid, &r.data, r.nodata.map(f64::from))
}

/// Write a u8 RGB GeoTIFF (no nodata).
pub(crate) fn write_rgb8(path: &Path, r: &Raster<[u8; 3]>) -> Result<()> {
    let flat: Vec<u8> = r.data.iter().flatten().copied().collect();
    write_image::<colortype::RGB8>(path, &r.grid, &flat, None)
}

/// Write an f32 GeoTIFF. GDAL_NODATA is `r.nodata`, or "nan" when there is none, because NaN is
/// always no-data in this crate's f32 layers and GDAL should know it.
pub fn write_f32(path: &Path, r: &Raster<f32>) -> Result<()> {
    let nd = r.nodata.map(f64::from).unwrap_or(f64::NAN);
    write_image::<colortype::Gray32Float>(path, &r.grid, &r.data, Some(nd))
}

/// Decode any supported TIFF (u8 gray, u8 RGB, f32 gray), with its georeference if tagged.
pub fn read_image(path: &Path) -> Result<Image> {
    // Read whole: the pixel data's chunks are then decoded in parallel, each by its own decoder.
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    decode_image(&bytes, path)
}

/// [`read_image`] on a file's bytes already in memory; `path` names the file in errors. Every
/// problem with the bytes is an [`Error::Input`], never a panic (`fuzz/fuzz_targets/geotiff_tile.rs`).
pub fn decode_image(bytes: &[u8], path: &Path) -> Result<Image> {
    let rerr = tiff_err(path, "not a readable TIFF (truncated or corrupt)");
    let mut limits = Limits::default();
    limits.decoding_buffer_size = MAX_DECODE_BYTES;
    let mut dec = Decoder::new(Cursor::new(bytes))
        .map_err(&rerr)?
        .with_limits(limits.clone());
    let (w, h) = dec.dimensions().map_err(&rerr)?;
    let color = dec.colortype().map_err(&rerr)?;
    let (width, height) = (w as usize, h as usize);
    let georef = read_georef(&mut dec, path)?;
    let nodata =
        match dec
            .find_tag(Tag::GdalNodata)
            .map_err(tiff_err(path, "GDAL_NODATA tag"))?
        {
            None => None,
            Some(v) => {
                let s = v
                    .into_string()
                    .map_err(tiff_err(path, "GDAL_NODATA tag is not text"))?;
                let t = s.trim().trim_end_matches('\0');
                Some(t.parse::<f64>().map_err(|_| {
                    Error::input(path, format!("GDAL_NODATA {t:?} is not a number"))
                })?)
            }
        };
    let data = match read_chunks_parallel(bytes, &mut dec, &limits) {
        Some(r) => r,
        None => dec.read_image(),
    }
    .map_err(tiff_err(
        path,
        "pixel data unreadable (truncated or corrupt)",
    ))?;
    let pixels = match (color, data) {
        (ColorType::Gray(8), DecodingResult::U8(v)) => Pixels::Gray8(v),
        (ColorType::RGB(8), DecodingResult::U8(v)) => Pixels::Rgb8(v),
        (ColorType::Gray(32), DecodingResult::F32(v)) => Pixels::F32(v),
        (c, d) => {
            let sample = match d {
                DecodingResult::U8(_) => "u8",
                DecodingResult::U16(_) => "u16",
                DecodingResult::U32(_) => "u32",
                DecodingResult::U64(_) => "u64",
                DecodingResult::F16(_) => "f16",
                DecodingResult::F32(_) => "f32",
                DecodingResult::F64(_) => "f64",
                DecodingResult::I8(_) => "i8",
                DecodingResult::I16(_) => "i16",
                DecodingResult::I32(_) => "i32",
                DecodingResult::I64(_) => "i64",
            };
            return Err(Error::input(
                path,
                format!(
                    "unsupported sample type {c:?} {sample} (supported: u8 gray, u8 RGB, f32 gray)"
                ),
            ));
        }
    };
    let expect = width
        * height
        * if matches!(pixels, Pixels::Rgb8(_)) {
            3
        } else {
            1
        };
    let got = match &pixels {
        Pixels::Gray8(v) | Pixels::Rgb8(v) => v.len(),
        Pixels::F32(v) => v.len(),
    };
    if got != expect {
        return Err(Error::input(
            path,
            format!("{width}x{height} image decoded to {got} samples, expected {expect}"),
        ));
    }
    let grid = georef.map(|g| GeoGrid { width, height, ..g });
    Ok(Image {
        width,
        height,
        pixels,
        grid,
        nodata,
    })
}

/// The first image's pixels as [`Decoder::read_image`] gives them, its strips or tiles decoded
/// on the thread pool (a tile's f32 height layer is several megabytes of deflated data, and
/// localization waits for it). `None` where that path does not apply — one chunk, planar
/// samples, a sample type the tile layers do not use — and the caller reads the image whole.
/// `dec` is a decoder over `bytes` at their first image. Every chunk is decompressed by its own
/// decoder over the same bytes, so the pixels are the
/// same as a serial read's. An image past the decoder's size limit, or whose chunk count does
/// not match its grid, is left to the serial read (which refuses it as before); the decoded
/// chunks are held until all are in, so a read peaks at twice the image.
fn read_chunks_parallel(
    bytes: &[u8],
    dec: &mut Decoder<Cursor<&[u8]>>,
    limits: &Limits,
) -> Option<tiff::TiffResult<DecodingResult>> {
    use rayon::prelude::*;
    let (w, h) = dec.dimensions().ok()?;
    let (width, height) = (w as usize, h as usize);
    let color = dec.colortype().ok()?;
    let samples = match color {
        ColorType::Gray(8) | ColorType::Gray(32) => 1,
        ColorType::RGB(8) => 3,
        _ => return None,
    };
    // `dec` (the caller's, over the same bytes) answers the layout; each worker opens its own.
    let open = || Decoder::new(Cursor::new(bytes)).map(|d| d.with_limits(limits.clone()));
    match dec.find_tag(Tag::PlanarConfiguration) {
        Ok(None) => {}
        Ok(Some(v)) if v.clone().into_u16().ok() == Some(1) => {}
        _ => return None,
    }
    let n = match dec.get_chunk_type() {
        ChunkType::Strip => dec.strip_count().ok()?,
        ChunkType::Tile => dec.tile_count().ok()?,
    };
    if n < 2 {
        return None;
    }
    let (cw, ch) = dec.chunk_dimensions();
    let (cw, ch) = (cw as usize, ch as usize);
    if cw == 0 || ch == 0 {
        return None;
    }
    let across = width.div_ceil(cw);
    // The whole image within the decoder's limit, and one chunk per cell of the chunk grid:
    // anything else is left to the serial read, which refuses it as before (before any
    // allocation here).
    let sample_bytes = if matches!(color, ColorType::Gray(32)) {
        4
    } else {
        1
    };
    let row = width.checked_mul(samples)?;
    let values = row.checked_mul(height)?;
    if values.checked_mul(sample_bytes)? > limits.decoding_buffer_size
        || n as usize != across.checked_mul(height.div_ceil(ch))?
    {
        return None;
    }
    // Decoded chunks in index order (row-major over the chunk grid), with their data size.
    let chunks: Vec<tiff::TiffResult<(DecodingResult, usize, usize)>> = (0..n)
        .into_par_iter()
        .map_init(
            || None,
            |slot: &mut Option<Decoder<Cursor<&[u8]>>>, i| {
                let dec = match slot {
                    Some(d) => d,
                    None => slot.insert(open()?),
                };
                let (dw, dh) = dec.chunk_data_dimensions(i);
                dec.read_chunk(i).map(|r| (r, dw as usize, dh as usize))
            },
        )
        .collect();
    // The first chunk's error, as the serial read would meet it, before the image is allocated.
    let chunks = match chunks.into_iter().collect::<tiff::TiffResult<Vec<_>>>() {
        Ok(c) => c,
        Err(e) => return Some(Err(e)),
    };
    let mut out = match color {
        ColorType::Gray(32) => DecodingResult::F32(vec![0.0; values]),
        _ => DecodingResult::U8(vec![0; values]),
    };
    for (i, (data, dw, dh)) in chunks.into_iter().enumerate() {
        let (x0, y0) = ((i % across) * cw, (i / across) * ch);
        if x0 + dw > width || y0 + dh > height {
            return None;
        }
        let placed = match (&mut out, &data) {
            (DecodingResult::F32(o), DecodingResult::F32(d)) => {
                place(o, d, row, x0, y0, dw, dh, samples)
            }
            (DecodingResult::U8(o), DecodingResult::U8(d)) => {
                place(o, d, row, x0, y0, dw, dh, samples)
            }
            _ => false,
        };
        if !placed {
            return None;
        }
    }
    Some(Ok(out))
}

/// Copy a `dw`×`dh` chunk of `samples`-sample pixels into `out` (rows of `row` values) at pixel
/// (`x0`, `y0`); false when the chunk holds fewer values than that.
#[allow(clippy::too_many_arguments)]
fn place<T: Copy>(
    out: &mut [T],
    chunk: &[T],
    row: usize,
    x0: usize,
    y0: usize,
    dw: usize,
    dh: usize,
    samples: usize,
) -> bool {
    let w = dw * samples;
    if chunk.len() < w * dh {
        return false;
    }
    for (r, src) in chunk.chunks_exact(w.max(1)).take(dh).enumerate() {
        let at = (y0 + r) * row + x0 * samples;
        out[at..at + w].copy_from_slice(src);
    }
    true
}

/// Georeference tags → a grid (width/height filled in by the caller); `None` if untagged.
fn read_georef<R: std::io::Read + std::io::Seek>(
    dec: &mut Decoder<R>,
    path: &Path,
) -> Result<Option<GeoGrid>> {
    let f64s = |dec: &mut Decoder<R>, tag: Tag, name: &str| -> Result<Option<Vec<f64>>> {
        match dec.find_tag(tag) {
            Ok(None) => Ok(None),
            Ok(Some(v)) => v
                .into_f64_vec()
                .map(Some)
                .map_err(|e| Error::input(path, format!("{name} tag: {e}"))),
            Err(e) => Err(Error::input(path, format!("{name} tag: {e}"))),
        }
    };
    let scale = f64s(dec, Tag::ModelPixelScaleTag, "ModelPixelScale")?;
    let tie = f64s(dec, Tag::ModelTiepointTag, "ModelTiepoint")?;
    let xform = f64s(dec, Tag::ModelTransformationTag, "ModelTransformation")?;
    let keys = match dec.find_tag(Tag::GeoKeyDirectoryTag) {
        Ok(None) => None,
        Ok(Some(v)) => Some(
            v.into_u16_vec()
                .map_err(|e| Error::input(path, format!("GeoKeyDirectory tag: {e}")))?,
        ),
        Err(e) => return Err(Error::input(path, format!("GeoKeyDirectory tag: {e}"))),
    };
    if scale.is_none() && tie.is_none() && xform.is_none() && keys.is_none() {
        return Ok(None);
    }
    let keys = keys.ok_or_else(|| {
        Error::input(
            path,
            "has georeference tags but no GeoKeyDirectory (no CRS)",
        )
    })?;
    let (crs, pixel_is_point) = parse_geokeys(&keys, path)?;

    // (x, y) of raster position (0, 0) and the pixel size.
    let (x, y, res) = if let (Some(s), Some(t)) = (&scale, &tie) {
        if s.len() < 2 || t.len() < 6 {
            return Err(Error::input(
                path,
                format!(
                    "ModelPixelScale has {} values (need 3), ModelTiepoint {} (need 6)",
                    s.len(),
                    t.len()
                ),
            ));
        }
        let (sx, sy) = (s[0], s[1]);
        check_square(sx, sy, path)?;
        // The tiepoint may name any raster position (i, j); move it to (0, 0).
        (t[3] - t[0] * sx, t[4] + t[1] * sy, sx)
    } else if let Some(m) = &xform {
        if m.len() != 16 {
            return Err(Error::input(
                path,
                format!("ModelTransformation has {} values, expected 16", m.len()),
            ));
        }
        let (a, b, d, e, f, hh) = (m[0], m[1], m[3], m[4], m[5], m[7]);
        if b.abs() > GEOREF_REL_TOL * a.abs() || e.abs() > GEOREF_REL_TOL * f.abs() {
            return Err(Error::input(
                path,
                format!(
                    "ModelTransformation is rotated or sheared (terms {b}, {e}); only north-up rasters are supported"
                ),
            ));
        }
        if !(f < 0.0) {
            return Err(Error::input(
                path,
                format!("ModelTransformation y scale {f} is not negative: raster is not north-up"),
            ));
        }
        check_square(a, -f, path)?;
        (d, hh, a)
    } else {
        return Err(Error::input(
            path,
            "GeoKeyDirectory present but neither ModelPixelScale+ModelTiepoint nor ModelTransformation",
        ));
    };
    // PixelIsPoint: (x, y) is the centre of pixel (0, 0); the outer corner is half a pixel out.
    let (x0, y0) = if pixel_is_point {
        (x - 0.5 * res, y + 0.5 * res)
    } else {
        (x, y)
    };
    if !x0.is_finite() || !y0.is_finite() {
        return Err(Error::input(path, "georeference origin is not finite"));
    }
    Ok(Some(GeoGrid {
        crs,
        x0,
        y0,
        res,
        width: 0,
        height: 0,
    }))
}

fn check_square(sx: f64, sy: f64, path: &Path) -> Result<()> {
    if !(sx > 0.0) || !(sy > 0.0) || !sx.is_finite() {
        return Err(Error::input(
            path,
            format!("pixel size {sx} x {sy} is not positive"),
        ));
    }
    if (sx - sy).abs() > GEOREF_REL_TOL * sx {
        return Err(Error::input(
            path,
            format!("pixels are not square ({sx} x {sy} m); resample to square pixels"),
        ));
    }
    Ok(())
}

/// GeoKeyDirectory → (CRS, PixelIsPoint?).
fn parse_geokeys(k: &[u16], path: &Path) -> Result<(Crs, bool)> {
    if k.len() < 4 {
        return Err(Error::input(
            path,
            "GeoKeyDirectory shorter than its header",
        ));
    }
    let n = k[3] as usize;
    if k.len() < 4 + 4 * n {
        return Err(Error::input(
            path,
            format!(
                "GeoKeyDirectory claims {n} keys but holds {}",
                (k.len() - 4) / 4
            ),
        ));
    }
    let (mut model, mut raster, mut projected, mut geographic) = (None, None, None, None);
    for e in k[4..4 + 4 * n].chunks_exact(4) {
        // Location 0 = the value is inline; other locations hold doubles/ASCII we do not need.
        let val = (e[1] == 0).then_some(e[3]);
        match e[0] {
            KEY_MODEL_TYPE => model = val,
            KEY_RASTER_TYPE => raster = val,
            KEY_PROJECTED_CS_TYPE => projected = val,
            KEY_GEOGRAPHIC_TYPE => geographic = val,
            _ => {}
        }
    }
    let pixel_is_point = match raster {
        None | Some(RASTER_PIXEL_IS_AREA) => false,
        Some(RASTER_PIXEL_IS_POINT) => true,
        Some(v) => {
            return Err(Error::input(
                path,
                format!("GTRasterTypeGeoKey {v} is neither PixelIsArea (1) nor PixelIsPoint (2)"),
            ))
        }
    };
    let crs = match (model, projected) {
        (Some(MODEL_TYPE_GEOGRAPHIC), _) => {
            let what = match geographic {
                Some(g) if g != USER_DEFINED => format!("EPSG:{g}"),
                _ => "user-defined".to_string(),
            };
            return Err(Error::input(
                path,
                format!(
                    "geographic CRS {what} (lat/lon pixels): a map tile needs a projected CRS ({}); reproject it",
                    geo::SUPPORTED_CRS
                ),
            ));
        }
        (_, Some(USER_DEFINED)) => {
            return Err(Error::input(
                path,
                format!(
                    "user-defined projected CRS (no EPSG code): unknown EPSG ({})",
                    geo::SUPPORTED_CRS
                ),
            ))
        }
        (_, Some(code)) => Crs::Epsg(u32::from(code)),
        (m, None) => {
            return Err(Error::input(
                path,
                format!(
                    "GeoKeyDirectory has no ProjectedCSTypeGeoKey (GTModelType {m:?}): unknown EPSG ({})",
                    geo::SUPPORTED_CRS
                ),
            ))
        }
    };
    geo::check_crs(crs).map_err(|e| Error::input(path, e.to_string()))?;
    Ok((crs, pixel_is_point))
}

fn require_grid(img: &Image, path: &Path) -> Result<GeoGrid> {
    img.grid.ok_or_else(|| {
        Error::input(
            path,
            "no georeference (no ModelPixelScale/ModelTiepoint/ModelTransformation/GeoKeyDirectory tags)",
        )
    })
}

fn wrong_type(path: &Path, got: &Pixels, want: &str) -> Error {
    Error::input(
        path,
        format!("sample type is {}, expected {want}", got.kind()),
    )
}

/// u8 nodata from GDAL_NODATA; it must be an integer 0..=255.
fn u8_nodata(v: Option<f64>, path: &Path) -> Result<Option<u8>> {
    match v {
        None => Ok(None),
        Some(x) if x.fract() == 0.0 && (0.0..=255.0).contains(&x) => Ok(Some(x as u8)),
        Some(x) => Err(Error::input(
            path,
            format!("GDAL_NODATA {x} is not a u8 value (0..255)"),
        )),
    }
}

/// Read a georeferenced u8 gray GeoTIFF.
pub fn read_gray8(path: &Path) -> Result<Raster<u8>> {
    let img = read_image(path)?;
    let grid = require_grid(&img, path)?;
    raster_gray8(img, grid, path)
}

/// An [`Image`] that must be u8 gray, on `grid`.
pub(crate) fn raster_gray8(img: Image, grid: GeoGrid, path: &Path) -> Result<Raster<u8>> {
    match img.pixels {
        Pixels::Gray8(data) => Ok(Raster {
            grid,
            data,
            nodata: u8_nodata(img.nodata, path)?,
        }),
        p => Err(wrong_type(path, &p, "u8 gray")),
    }
}

/// Read a georeferenced u8 RGB or gray GeoTIFF as RGB (gray replicated to three bands).
pub fn read_rgb8(path: &Path) -> Result<Raster<[u8; 3]>> {
    let img = read_image(path)?;
    let grid = require_grid(&img, path)?;
    raster_rgb8(img, grid, path)
}

/// An [`Image`] that must be u8 RGB or gray, on `grid`, as RGB. (A u8 nodata, if any, is
/// dropped: the satellite layer has none.)
pub(crate) fn raster_rgb8(img: Image, grid: GeoGrid, path: &Path) -> Result<Raster<[u8; 3]>> {
    let data = match img.pixels {
        Pixels::Rgb8(v) => v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        Pixels::Gray8(v) => v.into_iter().map(|g| [g, g, g]).collect(),
        p => return Err(wrong_type(path, &p, "u8 RGB or u8 gray")),
    };
    Ok(Raster {
        grid,
        data,
        nodata: None,
    })
}

/// Read a georeferenced f32 GeoTIFF (NaN GDAL_NODATA → `nodata: None`, NaN being no-data anyway).
pub fn read_f32(path: &Path) -> Result<Raster<f32>> {
    let img = read_image(path)?;
    let grid = require_grid(&img, path)?;
    raster_f32(img, grid, path)
}

/// An [`Image`] that must be f32, on `grid`.
pub(crate) fn raster_f32(img: Image, grid: GeoGrid, path: &Path) -> Result<Raster<f32>> {
    let nodata = match img.nodata {
        Some(v) if !v.is_nan() => Some(v as f32),
        _ => None,
    };
    match img.pixels {
        Pixels::F32(data) => Ok(Raster { grid, data, nodata }),
        p => Err(wrong_type(path, &p, "f32")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(w: usize, h: usize) -> GeoGrid {
        GeoGrid {
            crs: Crs::Epsg(32617),
            x0: 500_000.25,
            y0: 4_400_000.75,
            res: 0.1,
            width: w,
            height: h,
        }
    }

    #[test]
    fn roundtrip_all_kinds() {
        let dir = tempfile::tempdir().unwrap();
        let g = grid(7, 5);
        let r8 = Raster {
            grid: g,
            data: (0..35).map(|i| i as u8 * 7).collect(),
            nodata: Some(0),
        };
        let p = dir.path().join("g.tif");
        write_gray8(&p, &r8).unwrap();
        assert_eq!(read_gray8(&p).unwrap(), r8);

        let rgb = Raster {
            grid: g,
            data: (0..35)
                .map(|i| [i as u8, 2 * i as u8, 255 - i as u8])
                .collect(),
            nodata: None,
        };
        let p = dir.path().join("rgb.tif");
        write_rgb8(&p, &rgb).unwrap();
        assert_eq!(read_rgb8(&p).unwrap(), rgb);

        let mut f = Raster {
            grid: g,
            data: (0..35).map(|i| i as f32 * 0.5 - 3.0).collect(),
            nodata: Some(-9999.0),
        };
        f.data[3] = f32::NAN;
        let p = dir.path().join("f.tif");
        write_f32(&p, &f).unwrap();
        let back = read_f32(&p).unwrap();
        assert_eq!(back.grid, g);
        assert_eq!(back.nodata, Some(-9999.0));
        assert!(back.data[3].is_nan());
        assert_eq!(back.data[4], f.data[4]);
        // Type checks name the file and the type.
        let e = read_gray8(&p).unwrap_err().to_string();
        assert!(e.contains("f.tif") && e.contains("expected u8 gray"), "{e}");
    }

    /// The whole image as one serial read gives it.
    fn whole(bytes: &[u8]) -> DecodingResult {
        Decoder::new(Cursor::new(bytes))
            .unwrap()
            .read_image()
            .unwrap()
    }

    fn same(a: &DecodingResult, b: &DecodingResult) -> bool {
        match (a, b) {
            (DecodingResult::U8(a), DecodingResult::U8(b)) => a == b,
            (DecodingResult::F32(a), DecodingResult::F32(b)) => {
                a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
            }
            _ => false,
        }
    }

    #[test]
    fn chunks_decoded_in_parallel_equal_a_whole_read() {
        // Sizes past the writer's strip size (several strips each, the last one short); the
        // values vary along rows and columns so that a misplaced strip shows.
        let dir = tempfile::tempdir().unwrap();
        let (w, h) = (1013, 1207);
        let g = grid(w, h);
        let val = |i: usize| ((i % w) * 7 + (i / w) * 13) as f32 * 0.25 - 100.0;
        let mut f = Raster {
            grid: g,
            data: (0..w * h).map(val).collect(),
            nodata: Some(-9999.0),
        };
        f.data[5] = f32::NAN;
        let r8 = Raster {
            grid: g,
            data: (0..w * h).map(|i| val(i) as u8).collect(),
            nodata: Some(0),
        };
        let rgb = Raster {
            grid: g,
            data: (0..w * h)
                .map(|i| [i as u8, (i / w) as u8, (i % w) as u8])
                .collect(),
            nodata: None,
        };
        let files = [
            (
                "f.tif",
                write_f32(&dir.path().join("f.tif"), &f),
                ColorType::Gray(32),
            ),
            (
                "g.tif",
                write_gray8(&dir.path().join("g.tif"), &r8),
                ColorType::Gray(8),
            ),
            (
                "c.tif",
                write_rgb8(&dir.path().join("c.tif"), &rgb),
                ColorType::RGB(8),
            ),
        ];
        let limits = Limits::default();
        for (name, written, color) in files {
            written.unwrap();
            let bytes = std::fs::read(dir.path().join(name)).unwrap();
            let mut dec = Decoder::new(Cursor::new(&bytes[..])).unwrap();
            assert!(dec.strip_count().unwrap() > 1, "{name}: one strip");
            assert_eq!(dec.colortype().unwrap(), color, "{name}");
            let par = read_chunks_parallel(&bytes, &mut dec, &limits)
                .unwrap_or_else(|| panic!("{name}: not read in chunks"))
                .unwrap();
            assert!(same(&par, &whole(&bytes)), "{name}");
        }
        // And through the public readers.
        assert_eq!(read_gray8(&dir.path().join("g.tif")).unwrap(), r8);
        assert_eq!(read_rgb8(&dir.path().join("c.tif")).unwrap(), rgb);
        let back = read_f32(&dir.path().join("f.tif")).unwrap();
        assert!(back.data[5].is_nan());
        assert!(back
            .data
            .iter()
            .zip(&f.data)
            .all(|(a, b)| a.to_bits() == b.to_bits()));
        // A truncated file: the chunk that runs past the end is an error naming the file.
        let bytes = std::fs::read(dir.path().join("f.tif")).unwrap();
        let cut = dir.path().join("cut.tif");
        std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
        let e = read_f32(&cut).unwrap_err().to_string();
        assert!(e.contains("cut.tif"), "{e}");
    }

    /// A little-endian gray8 TIFF of two uncompressed strips whose header claims `w`×`h` pixels
    /// but whose strips hold 16 bytes between them.
    fn claimed_size_tiff(w: u32, h: u32) -> Vec<u8> {
        let mut b: Vec<u8> = b"II".to_vec();
        b.extend(42u16.to_le_bytes());
        b.extend(8u32.to_le_bytes());
        // (tag, type, count, value): 3 = SHORT, 4 = LONG; offsets 122 and 130 hold the arrays.
        let entries: [(u16, u16, u32, u32); 9] = [
            (256, 4, 1, w),
            (257, 4, 1, h),
            (258, 3, 1, 8),
            (259, 3, 1, 1),
            (262, 3, 1, 1),
            (273, 4, 2, 122),
            (277, 3, 1, 1),
            (278, 4, 1, h.div_ceil(2)),
            (279, 4, 2, 130),
        ];
        b.extend((entries.len() as u16).to_le_bytes());
        for (tag, typ, count, value) in entries {
            b.extend(tag.to_le_bytes());
            b.extend(typ.to_le_bytes());
            b.extend(count.to_le_bytes());
            b.extend(value.to_le_bytes());
        }
        b.extend(0u32.to_le_bytes());
        for v in [138u32, 146, 8, 8] {
            b.extend(v.to_le_bytes());
        }
        b.extend([7u8; 16]);
        b
    }

    #[test]
    fn a_claimed_size_past_the_limit_is_an_error_not_an_allocation() {
        let dir = tempfile::tempdir().unwrap();
        // 200 000 × 240 000 = 48 GB claimed in two strips: refused (as a whole read refuses it),
        // never allocated.
        let p = dir.path().join("huge.tif");
        std::fs::write(&p, claimed_size_tiff(200_000, 240_000)).unwrap();
        let e = read_gray8(&p).unwrap_err().to_string();
        assert!(e.contains("huge.tif"), "{e}");
        let bytes = std::fs::read(&p).unwrap();
        let limits = Limits::default();
        let chunked = |bytes: &[u8]| {
            let mut dec = Decoder::new(Cursor::new(bytes)).unwrap();
            read_chunks_parallel(bytes, &mut dec, &limits)
        };
        assert!(chunked(&bytes).is_none());
        // The same file at its true size reads, in chunks, as a whole read does.
        let bytes = claimed_size_tiff(4, 4);
        let par = chunked(&bytes).expect("read in chunks").unwrap();
        assert!(same(&par, &whole(&bytes)));
    }

    #[test]
    fn geokeys_reject_geographic_and_user_defined() {
        let p = Path::new("x.tif");
        let geog = [1, 1, 0, 2, 1024, 0, 1, 2, 2048, 0, 1, 4326];
        let e = parse_geokeys(&geog, p).unwrap_err().to_string();
        assert!(
            e.contains("x.tif") && e.contains("EPSG:4326") && e.contains("geographic CRS"),
            "{e}"
        );
        let user = [1, 1, 0, 2, 1024, 0, 1, 1, 3072, 0, 1, 32767];
        let e = parse_geokeys(&user, p).unwrap_err().to_string();
        assert!(e.contains("user-defined"), "{e}");
        let merc = [1, 1, 0, 2, 1024, 0, 1, 1, 3072, 0, 1, 3857];
        let e = parse_geokeys(&merc, p).unwrap_err().to_string();
        assert!(e.contains("EPSG:3857 is Web Mercator"), "{e}");
        let point = [1, 1, 0, 2, 1025, 0, 1, 2, 3072, 0, 1, 32633];
        assert_eq!(parse_geokeys(&point, p).unwrap(), (Crs::Epsg(32633), true));
    }
}
