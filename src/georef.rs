//! Georeferencing for the detection pipeline (I/O shell over [`crate::geo::georef`]): the
//! records `infraloc georef` prints and the service's `georef` request answers, the served pose's
//! georeferencing context the service holds in memory, and the lookup table it keeps beside the
//! pose file (docs/georef.md).

use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::geo::georef::{
    self, Ellipse, HeightIndex, HeightSurface, LookupTable, MapPoint, Params, PoseWithCovariance,
    Status, Surface, LUT_CHANNELS,
};
use crate::map::error::MapError;
use crate::map::{Crs, Raster};
use crate::posefile::PoseFile;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};

/// Schema name of a georef JSON document (`infraloc georef --format json`, the socket's answer).
pub const SCHEMA: &str = "infraloc.georef.v1";
/// Schema name of the lookup table's description.
pub const LUT_SCHEMA: &str = "infraloc.georef-lut.v1";
/// The lookup table's array, beside the pose file.
pub const LUT_FILE: &str = "georef_lut.npy";
/// The lookup table's description, beside the pose file.
pub const LUT_META_FILE: &str = "georef_lut.json";

/// The CSV header of [`to_csv`].
pub const CSV_HEADER: &str = "u,v,status,e,n,h,lat,lon,sigma_major_m,sigma_minor_m,angle_deg";

/// CSV text: the header, then one line per pixel (empty fields where the status is not ok).
pub fn to_csv(pixels: &[[f64; 2]], points: &[MapPoint]) -> String {
    let mut s = String::with_capacity(64 + 120 * points.len());
    s.push_str(CSV_HEADER);
    s.push('\n');
    for (p, m) in pixels.iter().zip(points) {
        s.push_str(&format!("{},{},{}", p[0], p[1], m.status.name()));
        if m.status == Status::Ok {
            let e = m.ellipse();
            let (lat, lon) = m.lat_lon.map_or((String::new(), String::new()), |[a, b]| {
                (format!("{a:.9}"), format!("{b:.9}"))
            });
            s.push_str(&format!(
                ",{:.4},{:.4},{:.4},{lat},{lon},{:.4},{:.4},{:.2}\n",
                m.enh[0], m.enh[1], m.enh[2], e.sigma_major_m, e.sigma_minor_m, e.angle_deg
            ));
        } else {
            s.push_str(",,,,,,,,\n");
        }
    }
    s
}

/// One pixel's JSON record (docs/georef.md): `u`, `v` (null when not finite) and `status`, and
/// for an `ok` pixel its point, ellipse, covariance, range and angle. Fields in name order: the
/// record serializes as the same record built as a JSON object (whose keys are sorted).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Record {
    #[serde(skip_serializing_if = "Option::is_none")]
    angle_deg: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    covariance_enh: Option<[[f64; 3]; 3]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    e: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    h: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    lat: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    lon: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    n: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    off_nadir_deg: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    range_m: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    sigma_major_m: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    sigma_minor_m: Option<f64>,
    status: &'static str,
    u: Option<f64>,
    v: Option<f64>,
}

impl Record {
    /// The record of pixel `px` georeferenced as `m`.
    pub fn of(px: [f64; 2], m: &MapPoint) -> Self {
        let num = |v: f64| v.is_finite().then_some(v);
        let mut r = Record {
            angle_deg: None,
            covariance_enh: None,
            e: None,
            h: None,
            lat: None,
            lon: None,
            n: None,
            off_nadir_deg: None,
            range_m: None,
            sigma_major_m: None,
            sigma_minor_m: None,
            status: m.status.name(),
            u: num(px[0]),
            v: num(px[1]),
        };
        if m.status == Status::Ok {
            let Ellipse {
                sigma_major_m,
                sigma_minor_m,
                angle_deg,
            } = m.ellipse();
            r.e = Some(m.enh[0]);
            r.n = Some(m.enh[1]);
            r.h = Some(m.enh[2]);
            if let Some([lat, lon]) = m.lat_lon {
                r.lat = Some(lat);
                r.lon = Some(lon);
            }
            r.sigma_major_m = Some(sigma_major_m);
            r.sigma_minor_m = Some(sigma_minor_m);
            r.angle_deg = Some(angle_deg);
            r.covariance_enh = Some(m.covariance);
            r.range_m = Some(m.range_m);
            r.off_nadir_deg = Some(m.off_nadir_deg);
        }
        r
    }
}

/// A georef document ([`SCHEMA`]): what `infraloc georef --format json` prints and the service's
/// `georef` request answers. Fields in name order, as [`Record`]'s.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Document {
    /// The map's CRS.
    pub crs: String,
    /// One record per pixel, in order.
    pub points: Vec<Record>,
    /// The pose used (see [`describe_pose`]).
    pub pose: Value,
    /// [`SCHEMA`].
    pub schema: &'static str,
    /// The surface the rays met: the tile and its smoothing and height σ, or the plane.
    pub surface: Value,
}

/// The map point of a [`Record`] read back as JSON (the inverse of it, for a client that prints an answer as
/// CSV); the error says what is missing.
pub fn point_of_record(r: &Value) -> std::result::Result<([f64; 2], MapPoint), String> {
    let coord = |k: &str| match &r[k] {
        Value::Null => Ok(f64::NAN),
        v => v.as_f64().ok_or(format!("{k} is not a number")),
    };
    let px = [coord("u")?, coord("v")?];
    let name = r["status"].as_str().ok_or("no status")?;
    let status = Status::from_name(name).ok_or(format!("unknown status {name:?}"))?;
    let mut m = MapPoint::invalid(status);
    if status == Status::Ok {
        let f = |k: &str| r[k].as_f64().ok_or(format!("{k} is missing"));
        m.enh = [f("e")?, f("n")?, f("h")?];
        m.lat_lon = match (r["lat"].as_f64(), r["lon"].as_f64()) {
            (Some(a), Some(b)) => Some([a, b]),
            _ => None,
        };
        m.covariance = serde_json::from_value(r["covariance_enh"].clone())
            .map_err(|e| format!("covariance_enh: {e}"))?;
        m.range_m = f("range_m")?;
        m.off_nadir_deg = f("off_nadir_deg")?;
    }
    Ok((px, m))
}

/// What names a pose in a georef document: the file, its `timestamp_utc`, `tile_id`, `crs`,
/// `quality.sigma` (null where absent), and whether it had a covariance.
pub fn describe_pose(file: &Path, pose: &Value, has_covariance: bool) -> Value {
    json!({
        "file": file.display().to_string(),
        "timestamp_utc": pose.get("timestamp_utc"),
        "tile_id": pose.get("tile_id"),
        "crs": pose.get("crs"),
        "sigma": pose.get("quality").and_then(|q| q.get("sigma")),
        "covariance": has_covariance,
    })
}

/// The served pose's georeferencing: the pose with its covariance, the camera and the tile's
/// height layer, held by the service from the moment the pose is served, so that a request
/// reads nothing from disk.
#[derive(Debug)]
pub struct ServedGeoref {
    pose: PoseWithCovariance,
    describe: Value,
    timestamp_utc: String,
    camera: Camera,
    height: Raster<f32>,
    /// The height layer's walking index, built once with the pose.
    index: HeightIndex,
    crs: Crs,
    tile_id: String,
}

impl ServedGeoref {
    /// The context of `pose` (read from `pose_path`, which errors name) with its camera and its
    /// tile's height layer. Errors: a malformed covariance, a CRS that is not the layer's, a
    /// layer without valid heights.
    pub fn new(
        pose: &PoseFile,
        pose_path: &Path,
        camera: Camera,
        height: Raster<f32>,
        tile_id: &str,
    ) -> Result<ServedGeoref> {
        let covariance = pose
            .pose_covariance()
            .map_err(|e| Error::input(pose_path, e.to_string()))?;
        let crs = height.grid.crs;
        if pose.crs != crs.to_string() {
            return Err(Error::input(
                pose_path,
                format!("crs {} differs from tile {tile_id}'s {crs}", pose.crs),
            ));
        }
        let Some(index) = HeightIndex::new(&height) else {
            return Err(MapError::NoHeights {
                id: tile_id.to_string(),
            }
            .into());
        };
        let v = serde_json::to_value(pose).unwrap_or_default();
        Ok(ServedGeoref {
            pose: PoseWithCovariance {
                pose: pose.pose(),
                covariance,
            },
            describe: describe_pose(pose_path, &v, covariance.is_some()),
            timestamp_utc: pose.timestamp_utc.clone(),
            camera,
            height,
            index,
            crs,
            tile_id: tile_id.to_string(),
        })
    }

    /// When the pose was computed (its `timestamp_utc`).
    pub fn timestamp_utc(&self) -> &str {
        &self.timestamp_utc
    }

    fn surface(&self) -> Surface<'_> {
        // Built in `new` from this very layer.
        Surface::Heights(
            HeightSurface::with_index(&self.height, &self.index).unwrap_or_else(|| {
                unreachable!("the index was built from the served height layer")
            }),
        )
    }

    /// The `georef` request's answer body: the [`SCHEMA`] document of the pixels (`None`: a
    /// non-finite coordinate) with `sigma_px`, or the one-line reason the request is refused
    /// (an empty batch, more than [`crate::control::MAX_GEOREF_PIXELS`] pixels, a bad σ).
    /// `height_sigma_m`: the height layer's σ, `None` for the layer's own estimate.
    pub fn answer(
        &self,
        pixels: &[[Option<f64>; 2]],
        sigma_px: f64,
        height_sigma_m: Option<f64>,
    ) -> std::result::Result<Document, String> {
        let max = crate::control::MAX_GEOREF_PIXELS;
        if pixels.is_empty() {
            return Err("georef: the batch has no pixels".into());
        }
        if pixels.len() > max {
            return Err(format!(
                "georef: {} pixels, more than the {max} one request may carry; split the batch",
                pixels.len()
            ));
        }
        if !(sigma_px.is_finite() && sigma_px >= 0.0) {
            return Err(format!(
                "georef: sigma_px {sigma_px}: must be a finite number ≥ 0"
            ));
        }
        if let Some(s) = height_sigma_m.filter(|s| !(s.is_finite() && *s >= 0.0)) {
            return Err(format!(
                "georef: height_sigma_m {s}: must be a finite number ≥ 0"
            ));
        }
        let px: Vec<[f64; 2]> = pixels
            .iter()
            .map(|[u, v]| [u.unwrap_or(f64::NAN), v.unwrap_or(f64::NAN)])
            .collect();
        let params = Params {
            sigma_px,
            height_sigma_m,
            ..Params::default()
        };
        let surface = self.surface();
        let points =
            georef::georef_batch(&self.camera, &self.pose, &surface, self.crs, &px, &params);
        Ok(Document {
            crs: self.crs.to_string(),
            points: px
                .iter()
                .zip(&points)
                .map(|(p, m)| Record::of(*p, m))
                .collect(),
            pose: self.describe.clone(),
            schema: SCHEMA,
            surface: json!({
                "tile_id": self.tile_id,
                "smoothing_m": self.index.smoothing_m(),
                "height_sigma_m": surface.height_sigma_m(&params),
            }),
        })
    }

    /// The lookup table at `step` px.
    pub fn lookup_table(&self, step: u32) -> LookupTable {
        georef::lookup_table(
            &self.camera,
            &self.pose,
            &self.surface(),
            step,
            &Params::default(),
        )
    }

    /// Write the lookup table at `step` px beside `pose_path`: [`LUT_FILE`] (NPY), then
    /// [`LUT_META_FILE`] (its description), each atomically. Returns the table's path.
    pub fn write_lookup_table(&self, pose_path: &Path, step: u32) -> Result<PathBuf> {
        let lut = self.lookup_table(step);
        let npy = pose_path.with_file_name(LUT_FILE);
        crate::persist::write_atomic(&npy, &npy_bytes(&lut))?;
        let ok = lut.cells.iter().filter(|c| c[0].is_finite()).count();
        let meta = json!({
            "schema": LUT_SCHEMA,
            "array": LUT_FILE,
            "dtype": "<f8",
            "shape": [lut.rows, lut.cols, LUT_CHANNELS.len()],
            "channels": LUT_CHANNELS,
            "step_px": lut.step,
            "image_width": self.camera.width(),
            "image_height": self.camera.height(),
            "cells_ok": ok,
            "crs": self.crs.to_string(),
            "max_off_nadir_deg": georef::DEFAULT_MAX_OFF_NADIR_DEG,
            "pose": self.describe,
        });
        let mut text = serde_json::to_string_pretty(&meta).unwrap_or_default();
        text.push('\n');
        crate::persist::write_atomic(&pose_path.with_file_name(LUT_META_FILE), text.as_bytes())?;
        Ok(npy)
    }
}

use crate::camera::CameraModel as _;

/// The table as an NPY file (format 1.0): little-endian float64, C order, shape
/// (rows, cols, 4); numpy's `np.load` reads it as it is.
pub fn npy_bytes(lut: &LookupTable) -> Vec<u8> {
    let dict = format!(
        "{{'descr': '<f8', 'fortran_order': False, 'shape': ({}, {}, {}), }}",
        lut.rows,
        lut.cols,
        LUT_CHANNELS.len()
    );
    // The header (magic 6, version 2, length 2, dict, padding, '\n') is a multiple of 64 bytes
    // so that the data is aligned, as the format asks.
    let unpadded = 10 + dict.len() + 1;
    let pad = unpadded.next_multiple_of(64) - unpadded;
    let header_len = (dict.len() + pad + 1) as u16;
    let mut out = Vec::with_capacity(unpadded + pad + lut.cells.len() * 32);
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&header_len.to_le_bytes());
    out.extend_from_slice(dict.as_bytes());
    out.extend(std::iter::repeat_n(b' ', pad));
    out.push(b'\n');
    for c in &lut.cells {
        for v in c {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn npy_header_is_aligned_and_the_data_little_endian() {
        let lut = LookupTable {
            step: 4,
            rows: 2,
            cols: 3,
            cells: (0..6).map(|k| [k as f64, 0.5, f64::NAN, -1.0]).collect(),
        };
        let b = npy_bytes(&lut);
        assert_eq!(&b[..8], b"\x93NUMPY\x01\x00");
        let hl = u16::from_le_bytes([b[8], b[9]]) as usize;
        assert_eq!((10 + hl) % 64, 0);
        let header = std::str::from_utf8(&b[10..10 + hl]).unwrap();
        assert!(
            header.starts_with("{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3, 4), }")
        );
        assert!(header.ends_with('\n'));
        assert_eq!(b.len(), 10 + hl + 6 * 4 * 8);
        let at =
            |i: usize| f64::from_le_bytes(b[10 + hl + 8 * i..18 + hl + 8 * i].try_into().unwrap());
        // Cell (1, 2) is the sixth: its first channel is 5.
        assert_eq!(at(5 * 4), 5.0);
        assert_eq!(at(5 * 4 + 1), 0.5);
        assert!(at(5 * 4 + 2).is_nan());
    }

    #[test]
    fn a_record_reads_back_as_its_point() {
        let mut m = MapPoint::invalid(Status::Ok);
        m.enh = [1.0, 2.0, 3.0];
        m.lat_lon = Some([45.0, 9.0]);
        m.covariance = [[1e-4, 0.0, 0.0], [0.0, 4e-4, 0.0], [0.0, 0.0, 1e-4]];
        m.range_m = 7.5;
        m.off_nadir_deg = 30.0;
        let (px, back) =
            point_of_record(&serde_json::to_value(Record::of([10.5, 20.0], &m)).unwrap()).unwrap();
        assert_eq!((px, back), ([10.5, 20.0], m));
        let bad = MapPoint::invalid(Status::NonFinite);
        let (px, back) =
            point_of_record(&serde_json::to_value(Record::of([f64::NAN, 1.0], &bad)).unwrap())
                .unwrap();
        assert!(px[0].is_nan() && back.status == Status::NonFinite);
        let e = point_of_record(&json!({"u": 1, "v": 2, "status": "fine"})).unwrap_err();
        assert_eq!(e, "unknown status \"fine\"");
    }
}
