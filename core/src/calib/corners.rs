//! Corner files: OpenCV FileStorage (XML or YAML) with `objectPoints` and `imagePoints`, one
//! matrix per view (N×1 with 3 resp. 2 channels, or N×3 / N×2), and the image size as `imageSize`
//! (`[w, h]`) or `image_width` / `image_height` — the layout of opencv_contrib's
//! `omni_calib_data.xml`. Pure: text in, [`Observations`] out.

use super::{Observations, View};
use crate::camera::import::{filestorage_matrix, filestorage_num, filestorage_tree, Node};
use crate::error::{Error, Result};
use std::path::Path;

/// Points of one view: `dim` coordinates each, from an N×1 `dim`-channel or N×`dim` matrix.
fn points<const D: usize>(n: &Node, key: &str, origin: &Path) -> Result<Vec<[f64; D]>> {
    let (r, c, ch, data) = filestorage_matrix(n, key, origin)?;
    if !((ch == D && (r == 1 || c == 1)) || (ch == 1 && c == D)) {
        return Err(Error::input(
            origin,
            format!("{key}: expected N×1 with {D} channels or N×{D}, found {r}×{c} with {ch}"),
        ));
    }
    Ok(data
        .chunks_exact(D)
        .map(|p| {
            let mut a = [0.0; D];
            a.copy_from_slice(p);
            a
        })
        .collect())
}

/// The views of a sequence key.
fn sequence<'a>(root: &'a Node, key: &str, origin: &Path) -> Result<Vec<&'a Node>> {
    match root.get(key) {
        None => Err(Error::input(origin, format!("missing key {key}"))),
        Some(Node::Seq(v)) => Ok(v.iter().collect()),
        // An empty sequence (`key:` or `<key></key>`): no views.
        Some(Node::Scalar(s)) if s.trim().is_empty() => Ok(Vec::new()),
        Some(m @ Node::Matrix { .. }) => Ok(vec![m]),
        Some(other) => Err(Error::input(
            origin,
            format!(
                "{key}: expected a sequence of matrices, found {}",
                other.kind()
            ),
        )),
    }
}

/// Image size: `imageSize` as `[w, h]` (YAML sequence, 2-element matrix, or OpenCV XML's
/// space-separated text), else `image_width` and `image_height`.
fn image_size(root: &Node, origin: &Path) -> Result<(u32, u32)> {
    let pixels = |v: f64, key: &str| -> Result<u32> {
        if v >= 1.0 && v.fract() == 0.0 && v <= u32::MAX as f64 {
            Ok(v as u32)
        } else {
            Err(Error::input(
                origin,
                format!("{key}: {v} is not a positive pixel count"),
            ))
        }
    };
    if let Some(n) = root.get("imageSize") {
        let vals: Vec<f64> = match n {
            Node::Scalar(s) => s
                .split_whitespace()
                .map(|t| t.parse::<f64>())
                .collect::<std::result::Result<_, _>>()
                .map_err(|_| {
                    Error::input(origin, format!("imageSize: {s:?} is not two numbers"))
                })?,
            Node::Seq(v) => v
                .iter()
                .map(|x| filestorage_num(x, "imageSize", origin))
                .collect::<Result<_>>()?,
            m @ Node::Matrix { .. } => filestorage_matrix(m, "imageSize", origin)?.3,
            Node::Map(_) => Vec::new(),
        };
        if vals.len() != 2 {
            return Err(Error::input(origin, "imageSize: expected [width, height]"));
        }
        return Ok((pixels(vals[0], "imageSize")?, pixels(vals[1], "imageSize")?));
    }
    match (root.get("image_width"), root.get("image_height")) {
        (Some(w), Some(h)) => Ok((
            pixels(filestorage_num(w, "image_width", origin)?, "image_width")?,
            pixels(filestorage_num(h, "image_height", origin)?, "image_height")?,
        )),
        _ => Err(Error::input(
            origin,
            "missing key imageSize (or image_width and image_height): the calibration needs the \
             image size",
        )),
    }
}

/// Parse a corners file. Views are named `view 0`, `view 1`, … in file order (OpenCV's indices).
pub fn parse_corners(text: &str, origin: &Path) -> Result<Observations> {
    let root = filestorage_tree(text, origin)?;
    let obj = sequence(&root, "objectPoints", origin)?;
    let img = sequence(&root, "imagePoints", origin)?;
    if obj.len() != img.len() {
        return Err(Error::input(
            origin,
            format!(
                "objectPoints has {} views but imagePoints has {}",
                obj.len(),
                img.len()
            ),
        ));
    }
    let (width, height) = image_size(&root, origin)?;
    let views = obj
        .iter()
        .zip(&img)
        .enumerate()
        .map(|(i, (o, p))| {
            let object = points::<3>(o, &format!("objectPoints[{i}]"), origin)?;
            let image = points::<2>(p, &format!("imagePoints[{i}]"), origin)?;
            Ok(View {
                name: format!("view {i}"),
                object,
                image,
            })
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(Observations {
        width,
        height,
        views,
    })
}

/// The observations as OpenCV FileStorage YAML in the same layout (what `--corners` reads), so
/// detected corners can be kept, edited, or fed to OpenCV.
pub fn to_corners_yaml(obs: &Observations) -> String {
    let mut s = String::from("%YAML:1.0\n---\n");
    s.push_str(&format!("imageSize: [ {}, {} ]\n", obs.width, obs.height));
    let block = |key: &str, channels: usize, rows: Vec<Vec<f64>>| -> String {
        if rows.is_empty() {
            return format!("{key}: []\n");
        }
        let mut out = format!("{key}:\n");
        for r in rows {
            let vals: Vec<String> = r.iter().map(|v| format!("{v:e}")).collect();
            out.push_str(&format!(
                "   - !!opencv-matrix\n      rows: {}\n      cols: 1\n      dt: \"{channels}d\"\n      data: [ {} ]\n",
                vals.len() / channels,
                vals.join(", ")
            ));
        }
        out
    };
    s.push_str(&block(
        "objectPoints",
        3,
        obs.views.iter().map(|v| v.object.concat()).collect(),
    ));
    s.push_str(&block(
        "imagePoints",
        2,
        obs.views.iter().map(|v| v.image.concat()).collect(),
    ));
    s
}
