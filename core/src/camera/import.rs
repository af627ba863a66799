//! Intrinsics files (docs/interfaces.md, "Camera intrinsics files"): OpenCV FileStorage (YAML or XML), Kalibr camchain YAML,
//! KITTI-360 MEI YAML and the native TOML table, detected from content; and the KITTI object
//! benchmark's calibration file ([`parse_kitti_calib`]: rectified pinholes plus the Velodyne →
//! camera extrinsic), which holds no image size and so becomes a camera only with one given
//! (`infraloc kitti import`).
//!
//! [`parse_camera`] is pure (text in, model out); the shell's `load_camera` reads the file. Every failure is an [`Error::Input`] naming the file and the key.
//!
//! The YAML and XML flavours are first turned into one small tree (`Node`) so that the OpenCV
//! key logic exists once for both syntaxes.

use super::{Camera, CameraError, Equidistant, Mei};
use crate::error::{Error, Result};
use std::path::Path;
use yaml_rust2::{Yaml, YamlLoader};

/// Separator between a camchain path and the camera to pick from it: `camchain.yaml#cam1`.
pub const CAMERA_SELECTOR: char = '#';

/// Parse intrinsics text in any supported format (the first camera of a camchain). `origin` is
/// used only in error messages.
pub fn parse_camera(text: &str, origin: &Path) -> Result<Camera> {
    parse_camera_named(text, origin, None)
}

/// Like [`parse_camera`], selecting a named camera (`cam1`) of a Kalibr camchain. Naming a camera
/// in a single-camera format is an error.
pub fn parse_camera_named(text: &str, origin: &Path, camera: Option<&str>) -> Result<Camera> {
    let ctx = Ctx { origin };
    if is_kitti_calib(text) {
        return Err(ctx.err(
            "a KITTI calibration file (P0..P3, R0_rect, Tr_velo_to_cam) holds no image size: \
             write a camera file from it with `infraloc kitti import --calib FILE --image PNG \
             --camera-out CAM.yaml --pose-out POSE.json`",
        ));
    }
    let cam = match detect(text) {
        Syntax::Xml => {
            let root = xml_tree(text, &ctx)?;
            no_selector(&ctx, camera, "OpenCV FileStorage XML")?;
            opencv(&root, &ctx)?
        }
        Syntax::Toml => {
            no_selector(&ctx, camera, "TOML")?;
            toml_camera(text, &ctx)?
        }
        Syntax::Yaml => {
            let root = yaml_tree(text, &ctx)?;
            if root.get("model_type").is_some() {
                no_selector(&ctx, camera, "KITTI-360 MEI YAML")?;
                kitti360(&root, &ctx)?
            } else if root.get("camera_matrix").is_some() {
                no_selector(&ctx, camera, "OpenCV FileStorage YAML")?;
                opencv(&root, &ctx)?
            } else if is_camchain(&root) {
                kalibr(&root, &ctx, camera)?
            } else {
                return Err(ctx.err(
                    "unrecognised intrinsics YAML: expected camera_matrix (OpenCV FileStorage), \
                     model_type (KITTI-360 MEI) or cam0.camera_model (Kalibr camchain)",
                ));
            }
        }
    };
    cam.validate().map_err(|m| ctx.err(m.to_string()))?;
    Ok(cam)
}

/// How uncertain a camera file's intrinsics are, 1σ, in the two modes that move a fisheye's
/// ground mapping most: a common scale of the focal lengths, and the principal point. A
/// calibration states them (`infraloc calibrate`'s parameter σ; the simulator's `hard` scenes,
/// whose given intrinsics are wrong on purpose, state the spread they were drawn from); the MI
/// refinement carries them into the pose's covariance ([`crate::localize::refine::uncertainty`]).
/// OpenCV FileStorage keys `sigma_focal_rel` and `sigma_principal_point_px`, both optional.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct IntrinsicsSigma {
    /// σ of the focal lengths' common scale, relative (0.002 = 0.2 %).
    pub focal_rel: f64,
    /// σ of each principal-point coordinate, pixels.
    pub principal_point_px: f64,
}

impl IntrinsicsSigma {
    /// The three independent 1σ perturbations of `cam`: focal scale, cx, cy (a mode whose σ is
    /// 0 is left out).
    pub(crate) fn perturbed(&self, cam: &Camera) -> Vec<Camera> {
        let mut out = Vec::new();
        let apply = |f: &dyn Fn(&mut f64, &mut f64, &mut f64, &mut f64)| {
            let mut c = cam.clone();
            match &mut c {
                Camera::Mei(m) => f(&mut m.fx, &mut m.fy, &mut m.cx, &mut m.cy),
                Camera::Equidistant(e) => {
                    f(&mut e.fx, &mut e.fy, &mut e.cx, &mut e.cy);
                    e.cache = Default::default();
                }
            }
            c
        };
        if self.focal_rel > 0.0 {
            let k = 1.0 + self.focal_rel;
            out.push(apply(&|fx, fy, _, _| {
                *fx *= k;
                *fy *= k;
            }));
        }
        if self.principal_point_px > 0.0 {
            let d = self.principal_point_px;
            out.push(apply(&|_, _, cx, _| *cx += d));
            out.push(apply(&|_, _, _, cy| *cy += d));
        }
        out
    }

    /// The FileStorage YAML lines for these σ (appended to [`to_opencv_yaml`]'s output).
    pub fn yaml_lines(&self) -> String {
        format!(
            "sigma_focal_rel: {}\nsigma_principal_point_px: {}\n",
            real(self.focal_rel),
            real(self.principal_point_px)
        )
    }
}

/// The intrinsics' stated uncertainty in an OpenCV FileStorage file (YAML or XML), if it states
/// one (see [`IntrinsicsSigma`]); other formats state none. A key that is present but not a
/// finite number ≥ 0 (or a focal σ of 50 % or more) is an error naming it.
pub fn parse_intrinsics_sigma(text: &str, origin: &Path) -> Result<Option<IntrinsicsSigma>> {
    let ctx = Ctx { origin };
    let root = match detect(text) {
        Syntax::Xml => xml_tree(text, &ctx)?,
        Syntax::Yaml if !is_kitti_calib(text) => yaml_tree(text, &ctx)?,
        _ => return Ok(None),
    };
    let f = opt_num(&root, "sigma_focal_rel", &ctx)?;
    let c = opt_num(&root, "sigma_principal_point_px", &ctx)?;
    if f.is_none() && c.is_none() {
        return Ok(None);
    }
    let s = IntrinsicsSigma {
        focal_rel: f.unwrap_or(0.0),
        principal_point_px: c.unwrap_or(0.0),
    };
    for (key, v, max) in [
        ("sigma_focal_rel", s.focal_rel, 0.5),
        (
            "sigma_principal_point_px",
            s.principal_point_px,
            f64::INFINITY,
        ),
    ] {
        if !(v.is_finite() && v >= 0.0 && v < max) {
            return Err(ctx.err(format!("{key}: {v} is not a finite σ ≥ 0 (and < {max})")));
        }
    }
    Ok(Some(s))
}

fn no_selector(ctx: &Ctx, camera: Option<&str>, format: &str) -> Result<()> {
    match camera {
        Some(c) => Err(ctx.err(format!(
            "camera {c:?} selected, but a {format} file holds one camera (only Kalibr camchains \
             hold several)"
        ))),
        None => Ok(()),
    }
}

/// Error context: the file being parsed.
struct Ctx<'a> {
    origin: &'a Path,
}

impl Ctx<'_> {
    fn err(&self, msg: impl Into<String>) -> Error {
        Error::input(self.origin, msg)
    }
}

// ---------------------------------------------------------------------------------------------
// Syntax detection and the common tree
// ---------------------------------------------------------------------------------------------

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Syntax {
    Yaml,
    Xml,
    Toml,
}

/// Decide the syntax from the first significant line: XML starts with `<`, YAML files start with a
/// `%YAML` directive, `---`, or `key:`; anything else (`[table]`, `key = value`) is TOML.
fn detect(text: &str) -> Syntax {
    let first = text
        .lines()
        .map(|l| l.trim_start_matches('\u{feff}').trim())
        .find(|l| !l.is_empty() && !l.starts_with('#'))
        .unwrap_or("");
    if first.starts_with('<') {
        return Syntax::Xml;
    }
    if first.starts_with("%YAML") || first.starts_with("---") {
        return Syntax::Yaml;
    }
    let colon = first.find(':');
    let equals = first.find('=');
    match (colon, equals) {
        (Some(c), Some(e)) if c < e => Syntax::Yaml,
        (Some(_), None) => Syntax::Yaml,
        _ => Syntax::Toml,
    }
}

/// A FileStorage-like tree: what OpenCV YAML, OpenCV XML and plain YAML have in common.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Node {
    /// A scalar, as text (numbers are parsed on use, so errors can name the key).
    Scalar(String),
    /// A mapping in file order.
    Map(Vec<(String, Node)>),
    /// A sequence.
    Seq(Vec<Node>),
    /// An `opencv-matrix`: `rows`, `cols`, `dt` and `data` (still text).
    Matrix {
        rows: String,
        cols: String,
        dt: String,
        data: Vec<String>,
    },
}

impl Node {
    pub(crate) fn get(&self, key: &str) -> Option<&Node> {
        match self {
            Node::Map(m) => m.iter().find(|(k, _)| k == key).map(|(_, v)| v),
            _ => None,
        }
    }

    pub(crate) fn kind(&self) -> &'static str {
        match self {
            Node::Scalar(_) => "a scalar",
            Node::Map(_) => "a mapping",
            Node::Seq(_) => "a sequence",
            Node::Matrix { .. } => "a matrix",
        }
    }
}

/// Turn the `%YAML:1.0` directive OpenCV writes (not valid YAML: the standard form has a space) into
/// a blank line, keeping line numbers for error messages.
fn strip_opencv_directive(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for (i, line) in text.lines().enumerate() {
        if i < 2 && line.trim_start_matches('\u{feff}').starts_with("%YAML") {
            out.push('\n');
        } else {
            out.push_str(line);
            out.push('\n');
        }
    }
    out
}

fn yaml_tree(text: &str, ctx: &Ctx) -> Result<Node> {
    // yaml-rust2 drops local tags such as `!!opencv-matrix` on mappings; the matrix is recognised by
    // its rows/cols/dt/data keys instead.
    let docs = YamlLoader::load_from_str(&strip_opencv_directive(text))
        .map_err(|e| ctx.err(format!("YAML syntax: {e}")))?;
    let doc = docs
        .into_iter()
        .next()
        .ok_or_else(|| ctx.err("empty YAML document"))?;
    yaml_node(&doc, ctx, "")
}

fn yaml_scalar(y: &Yaml) -> Option<String> {
    match y {
        Yaml::Real(s) | Yaml::String(s) => Some(s.clone()),
        Yaml::Integer(i) => Some(i.to_string()),
        Yaml::Boolean(b) => Some(b.to_string()),
        _ => None,
    }
}

fn yaml_node(y: &Yaml, ctx: &Ctx, path: &str) -> Result<Node> {
    Ok(match y {
        Yaml::Hash(h) => {
            let mut m = Vec::with_capacity(h.len());
            for (k, v) in h {
                let key = yaml_scalar(k)
                    .ok_or_else(|| ctx.err(format!("{path}: mapping key is not a scalar")))?;
                let sub = if path.is_empty() {
                    key.clone()
                } else {
                    format!("{path}.{key}")
                };
                m.push((key, yaml_node(v, ctx, &sub)?));
            }
            let node = Node::Map(m);
            match (
                node.get("rows"),
                node.get("cols"),
                node.get("dt"),
                node.get("data"),
            ) {
                (Some(Node::Scalar(r)), Some(Node::Scalar(c)), dt, Some(Node::Seq(d))) => {
                    let data = d
                        .iter()
                        .map(|n| match n {
                            Node::Scalar(s) => Ok(s.clone()),
                            other => Err(ctx.err(format!(
                                "{path}.data: expected numbers, found {}",
                                other.kind()
                            ))),
                        })
                        .collect::<Result<Vec<_>>>()?;
                    let dt = match dt {
                        Some(Node::Scalar(s)) => s.clone(),
                        _ => "d".into(),
                    };
                    Node::Matrix {
                        rows: r.clone(),
                        cols: c.clone(),
                        dt,
                        data,
                    }
                }
                _ => node,
            }
        }
        Yaml::Array(a) => Node::Seq(
            a.iter()
                .enumerate()
                .map(|(i, v)| yaml_node(v, ctx, &format!("{path}[{i}]")))
                .collect::<Result<_>>()?,
        ),
        Yaml::Null => Node::Scalar(String::new()),
        other => Node::Scalar(
            yaml_scalar(other)
                .ok_or_else(|| ctx.err(format!("{path}: unsupported YAML value (alias?)")))?,
        ),
    })
}

/// OpenCV writes strings in XML bare, or in double quotes when they contain spaces or digits first.
fn unquote(s: &str) -> &str {
    let s = s.trim();
    s.strip_prefix('"')
        .and_then(|t| t.strip_suffix('"'))
        .unwrap_or(s)
}

fn xml_tree(text: &str, ctx: &Ctx) -> Result<Node> {
    let doc = roxmltree::Document::parse(text).map_err(|e| ctx.err(format!("XML syntax: {e}")))?;
    let root = doc.root_element();
    if root.tag_name().name() != "opencv_storage" {
        return Err(ctx.err(format!(
            "XML root element is <{}>, expected <opencv_storage> (OpenCV FileStorage)",
            root.tag_name().name()
        )));
    }
    xml_node(root, ctx)
}

fn xml_node(e: roxmltree::Node, ctx: &Ctx) -> Result<Node> {
    let name = e.tag_name().name();
    let children: Vec<_> = e.children().filter(|c| c.is_element()).collect();
    if e.attribute("type_id") == Some("opencv-matrix") {
        let field = |k: &str| {
            children
                .iter()
                .find(|c| c.tag_name().name() == k)
                .map(|c| c.text().unwrap_or("").trim().to_string())
                .ok_or_else(|| ctx.err(format!("{name}: opencv-matrix without <{k}>")))
        };
        return Ok(Node::Matrix {
            rows: field("rows")?,
            cols: field("cols")?,
            dt: unquote(&field("dt")?).to_string(),
            data: field("data")?
                .split_whitespace()
                .map(str::to_string)
                .collect(),
        });
    }
    if children.is_empty() {
        return Ok(Node::Scalar(unquote(e.text().unwrap_or("")).to_string()));
    }
    if children.iter().all(|c| c.tag_name().name() == "_") {
        return Ok(Node::Seq(
            children
                .iter()
                .map(|c| xml_node(*c, ctx))
                .collect::<Result<_>>()?,
        ));
    }
    Ok(Node::Map(
        children
            .iter()
            .map(|c| Ok((c.tag_name().name().to_string(), xml_node(*c, ctx)?)))
            .collect::<Result<_>>()?,
    ))
}

// ---------------------------------------------------------------------------------------------
// Typed access with key-naming errors
// ---------------------------------------------------------------------------------------------

fn req<'a>(n: &'a Node, key: &str, ctx: &Ctx) -> Result<&'a Node> {
    n.get(key)
        .ok_or_else(|| ctx.err(format!("missing key {key}")))
}

fn parse_f64(s: &str, key: &str, ctx: &Ctx) -> Result<f64> {
    s.trim()
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite())
        .ok_or_else(|| ctx.err(format!("{key}: {s:?} is not a finite number")))
}

/// A number: a scalar, or a 1×1 matrix (OpenCV writes `xi` either way).
fn num(n: &Node, key: &str, ctx: &Ctx) -> Result<f64> {
    match n {
        Node::Scalar(s) => parse_f64(s, key, ctx),
        Node::Matrix { .. } => {
            let (r, c, d) = matrix(n, key, ctx)?;
            if d.len() != 1 {
                return Err(ctx.err(format!("{key}: expected a number, found a {r}×{c} matrix")));
            }
            Ok(d[0])
        }
        Node::Seq(v) if v.len() == 1 => num(&v[0], key, ctx),
        other => Err(ctx.err(format!("{key}: expected a number, found {}", other.kind()))),
    }
}

fn req_num(n: &Node, key: &str, ctx: &Ctx) -> Result<f64> {
    num(req(n, key, ctx)?, key, ctx)
}

fn opt_num(n: &Node, key: &str, ctx: &Ctx) -> Result<Option<f64>> {
    n.get(key).map(|v| num(v, key, ctx)).transpose()
}

/// An image dimension: a positive integer.
fn dim(n: &Node, key: &str, ctx: &Ctx) -> Result<u32> {
    let v = num(n, key, ctx)?;
    if v >= 1.0 && v.fract() == 0.0 && v <= u32::MAX as f64 {
        Ok(v as u32)
    } else {
        Err(ctx.err(format!("{key}: {v} is not a positive integer pixel count")))
    }
}

fn string<'a>(n: &'a Node, key: &str, ctx: &Ctx) -> Result<&'a str> {
    match n {
        Node::Scalar(s) => Ok(s.as_str()),
        other => Err(ctx.err(format!("{key}: expected a string, found {}", other.kind()))),
    }
}

/// Parse an opencv-matrix: (rows, cols, row-major data). Checks the element count against the
/// declared shape and channel count (`dt` such as `d`, `f` or `3d`).
fn matrix(n: &Node, key: &str, ctx: &Ctx) -> Result<(usize, usize, Vec<f64>)> {
    if let Node::Matrix { dt, .. } = n {
        let channels = dt
            .trim()
            .trim_end_matches(|ch: char| ch.is_ascii_alphabetic());
        if !channels.is_empty() && channels != "1" {
            return Err(ctx.err(format!(
                "{key}.dt: {dt:?} is a {channels}-channel matrix, expected one channel"
            )));
        }
    }
    let (r, c, _, values) = matrix_any(n, key, ctx)?;
    Ok((r, c, values))
}

/// Parse an opencv-matrix of any channel count: (rows, cols, channels, interleaved data).
fn matrix_any(n: &Node, key: &str, ctx: &Ctx) -> Result<(usize, usize, usize, Vec<f64>)> {
    let Node::Matrix {
        rows,
        cols,
        dt,
        data,
    } = n
    else {
        return Err(ctx.err(format!(
            "{key}: expected an opencv-matrix (rows, cols, dt, data), found {}",
            n.kind()
        )));
    };
    let int = |s: &str, what: &str| {
        s.trim()
            .parse::<usize>()
            .map_err(|_| ctx.err(format!("{key}.{what}: {s:?} is not a non-negative integer")))
    };
    let (r, c) = (int(rows, "rows")?, int(cols, "cols")?);
    let channels = match dt
        .trim()
        .trim_end_matches(|ch: char| ch.is_ascii_alphabetic())
    {
        "" => 1,
        digits => int(digits, "dt")?,
    };
    let values = data
        .iter()
        .map(|s| parse_f64(s, &format!("{key}.data"), ctx))
        .collect::<Result<Vec<_>>>()?;
    if values.len() != r * c * channels {
        let shape = if channels == 1 {
            format!("{r}×{c}")
        } else {
            format!("{r}×{c} of {channels} channels")
        };
        return Err(ctx.err(format!(
            "{key}: declared {shape} but data holds {} values",
            values.len()
        )));
    }
    Ok((r, c, channels, values))
}

/// Parse OpenCV FileStorage text (YAML or XML, detected from content) into the common tree, for
/// readers of FileStorage files other than intrinsics (the calibrator's corner files).
pub(crate) fn filestorage_tree(text: &str, origin: &Path) -> Result<Node> {
    let ctx = Ctx { origin };
    match detect(text) {
        Syntax::Xml => xml_tree(text, &ctx),
        Syntax::Yaml => yaml_tree(text, &ctx),
        Syntax::Toml => Err(ctx.err("not an OpenCV FileStorage file (expected XML or YAML)")),
    }
}

/// [`matrix_any`] for readers outside this module: (rows, cols, channels, interleaved data).
pub(crate) fn filestorage_matrix(
    n: &Node,
    key: &str,
    origin: &Path,
) -> Result<(usize, usize, usize, Vec<f64>)> {
    matrix_any(n, key, &Ctx { origin })
}

/// A number (scalar, 1×1 matrix or one-element sequence) for readers outside this module.
pub(crate) fn filestorage_num(n: &Node, key: &str, origin: &Path) -> Result<f64> {
    num(n, key, &Ctx { origin })
}

/// A list of numbers: a YAML sequence, or a 1×N / N×1 matrix.
fn vector(n: &Node, key: &str, ctx: &Ctx) -> Result<Vec<f64>> {
    match n {
        Node::Seq(v) => v
            .iter()
            .map(|x| num(x, key, ctx))
            .collect::<Result<Vec<_>>>(),
        Node::Matrix { .. } => {
            let (r, c, d) = matrix(n, key, ctx)?;
            if r != 1 && c != 1 {
                return Err(ctx.err(format!("{key}: expected 1×N or N×1, found {r}×{c}")));
            }
            Ok(d)
        }
        other => Err(ctx.err(format!("{key}: expected a list, found {}", other.kind()))),
    }
}

fn vector_len<const N: usize>(n: &Node, key: &str, ctx: &Ctx) -> Result<[f64; N]> {
    let v = vector(n, key, ctx)?;
    let len = v.len();
    v.try_into()
        .map_err(|_| ctx.err(format!("{key}: expected {N} values, found {len}")))
}

// ---------------------------------------------------------------------------------------------
// Formats
// ---------------------------------------------------------------------------------------------

/// OpenCV FileStorage (YAML or XML) from `cv::omnidir` / `cv::fisheye` calibration tooling.
fn opencv(root: &Node, ctx: &Ctx) -> Result<Camera> {
    let kn = req(root, "camera_matrix", ctx)?;
    let (r, c, k) = matrix(kn, "camera_matrix", ctx)?;
    if (r, c) != (3, 3) {
        return Err(ctx.err(format!("camera_matrix: expected 3×3, found {r}×{c}")));
    }
    if k[3] != 0.0 || k[6] != 0.0 || k[7] != 0.0 || k[8] != 1.0 {
        return Err(ctx.err(format!(
            "camera_matrix: not upper-triangular with K[2][2] = 1 (rows 2–3: {:?}, {:?})",
            &k[3..6],
            &k[6..9]
        )));
    }
    let size_key = |key: &str| {
        let n = root.get(key).ok_or_else(|| {
            ctx.err(format!(
                "missing key {key}: the camera model needs the image size (OpenCV calibration \
                 output does not store it; add image_width and image_height)"
            ))
        })?;
        dim(n, key, ctx)
    };
    let (width, height) = (size_key("image_width")?, size_key("image_height")?);
    let dist = vector_len::<4>(
        req(root, "distortion_coefficients", ctx)?,
        "distortion_coefficients",
        ctx,
    )?;
    let fov_deg = opt_num(root, "fov_deg", ctx)?;
    let model = match root.get("model") {
        Some(n) => string(n, "model", ctx)?.to_ascii_lowercase(),
        None => "mei".into(),
    };
    match model.as_str() {
        "mei" | "omnidir" => Ok(Camera::Mei(Mei {
            width,
            height,
            fx: k[0],
            fy: k[4],
            cx: k[2],
            cy: k[5],
            skew: k[1],
            xi: req_num(root, "xi", ctx)?,
            k1: dist[0],
            k2: dist[1],
            p1: dist[2],
            p2: dist[3],
            fov_deg,
        })),
        "equidistant" | "fisheye" => {
            if root.get("xi").is_some() {
                return Err(ctx.err("xi: not a parameter of model: equidistant"));
            }
            Ok(Camera::Equidistant(Equidistant {
                width,
                height,
                fx: k[0],
                fy: k[4],
                cx: k[2],
                cy: k[5],
                // cv::fisheye stores the skew as K[0][1] = α·fx.
                alpha: k[1] / k[0],
                k1: dist[0],
                k2: dist[1],
                k3: dist[2],
                k4: dist[3],
                fov_deg,
                cache: Default::default(),
            }))
        }
        other => Err(ctx.err(format!(
            "model: {other:?} is not supported (expected mei or equidistant)"
        ))),
    }
}

/// KITTI-360 / CamOdoCal MEI YAML.
fn kitti360(root: &Node, ctx: &Ctx) -> Result<Camera> {
    let model = string(req(root, "model_type", ctx)?, "model_type", ctx)?;
    if !model.eq_ignore_ascii_case("MEI") {
        return Err(ctx.err(format!(
            "model_type: {model:?} is not supported (expected MEI)"
        )));
    }
    let section = |name: &str| req(root, name, ctx);
    let sub = |sec: &str, key: &str| -> Result<f64> {
        let s = section(sec)?;
        let full = format!("{sec}.{key}");
        let n = s
            .get(key)
            .ok_or_else(|| ctx.err(format!("missing key {full}")))?;
        num(n, &full, ctx)
    };
    Ok(Camera::Mei(Mei {
        width: dim(req(root, "image_width", ctx)?, "image_width", ctx)?,
        height: dim(req(root, "image_height", ctx)?, "image_height", ctx)?,
        fx: sub("projection_parameters", "gamma1")?,
        fy: sub("projection_parameters", "gamma2")?,
        cx: sub("projection_parameters", "u0")?,
        cy: sub("projection_parameters", "v0")?,
        skew: 0.0,
        xi: sub("mirror_parameters", "xi")?,
        k1: sub("distortion_parameters", "k1")?,
        k2: sub("distortion_parameters", "k2")?,
        // KITTI-360's devkit ignores p1/p2 when projecting; the calibration has them, so we keep them.
        p1: sub("distortion_parameters", "p1")?,
        p2: sub("distortion_parameters", "p2")?,
        fov_deg: opt_num(root, "fov_deg", ctx)?,
    }))
}

fn is_camchain(root: &Node) -> bool {
    match root {
        Node::Map(m) => m.iter().any(|(_, v)| v.get("camera_model").is_some()),
        _ => false,
    }
}

/// Kalibr camchain: `omni` or `pinhole` projection with `radtan`, `equidistant` or `none`
/// distortion.
fn kalibr(root: &Node, ctx: &Ctx, camera: Option<&str>) -> Result<Camera> {
    let Node::Map(m) = root else {
        return Err(ctx.err("camchain: expected a mapping of cameras"));
    };
    let (name, cam) = match camera {
        Some(c) => (
            c.to_string(),
            root.get(c).ok_or_else(|| {
                let names: Vec<&str> = m.iter().map(|(k, _)| k.as_str()).collect();
                ctx.err(format!(
                    "camera {c:?} not in camchain (has {})",
                    names.join(", ")
                ))
            })?,
        ),
        None => m
            .iter()
            .find(|(_, v)| v.get("camera_model").is_some())
            .map(|(k, v)| (k.clone(), v))
            .ok_or_else(|| ctx.err("camchain: no camera with camera_model"))?,
    };
    let key = |k: &str| format!("{name}.{k}");
    let get = |k: &str| {
        cam.get(k)
            .ok_or_else(|| ctx.err(format!("missing key {}", key(k))))
    };
    let model = string(get("camera_model")?, &key("camera_model"), ctx)?;
    let intr = vector(get("intrinsics")?, &key("intrinsics"), ctx)?;
    let res = vector_len::<2>(get("resolution")?, &key("resolution"), ctx)?;
    let size = |v: f64, what: &str| dim(&Node::Scalar(v.to_string()), &key(what), ctx);
    let (width, height) = (size(res[0], "resolution")?, size(res[1], "resolution")?);
    let dist_model = match cam.get("distortion_model") {
        Some(n) => string(n, &key("distortion_model"), ctx)?,
        None => "none",
    };
    let coeffs = match cam.get("distortion_coeffs") {
        Some(n) => vector(n, &key("distortion_coeffs"), ctx)?,
        None => Vec::new(),
    };
    let coeffs4 = |expected: &str| -> Result<[f64; 4]> {
        coeffs.as_slice().try_into().map_err(|_| {
            ctx.err(format!(
                "{}: {expected} needs 4 coefficients, found {}",
                key("distortion_coeffs"),
                coeffs.len()
            ))
        })
    };
    let dist = match dist_model {
        "radtan" | "equidistant" => coeffs4(dist_model)?,
        "none" if coeffs.iter().all(|c| *c == 0.0) => [0.0; 4],
        other => {
            return Err(ctx.err(format!(
                "{}: {other:?} is not supported (expected radtan, equidistant or none)",
                key("distortion_model")
            )))
        }
    };
    let expect_len = |n: usize| -> Result<()> {
        if intr.len() == n {
            Ok(())
        } else {
            Err(ctx.err(format!(
                "{}: camera_model {model} needs {n} values, found {}",
                key("intrinsics"),
                intr.len()
            )))
        }
    };
    let mei = |xi: f64, f: &[f64]| {
        Camera::Mei(Mei {
            width,
            height,
            fx: f[0],
            fy: f[1],
            cx: f[2],
            cy: f[3],
            skew: 0.0,
            xi,
            k1: dist[0],
            k2: dist[1],
            p1: dist[2],
            p2: dist[3],
            fov_deg: None,
        })
    };
    match (model, dist_model) {
        ("omni", "radtan" | "none") => {
            expect_len(5)?;
            Ok(mei(intr[0], &intr[1..]))
        }
        ("pinhole", "radtan" | "none") => {
            expect_len(4)?;
            Ok(mei(0.0, &intr))
        }
        ("pinhole", "equidistant") => {
            expect_len(4)?;
            Ok(Camera::Equidistant(Equidistant {
                width,
                height,
                fx: intr[0],
                fy: intr[1],
                cx: intr[2],
                cy: intr[3],
                alpha: 0.0,
                k1: dist[0],
                k2: dist[1],
                k3: dist[2],
                k4: dist[3],
                fov_deg: None,
                cache: Default::default(),
            }))
        }
        ("omni", _) => Err(ctx.err(format!(
            "{}: {dist_model} with camera_model omni is not supported (expected radtan)",
            key("distortion_model")
        ))),
        (other, _) => Err(ctx.err(format!(
            "{}: {other:?} is not supported (expected omni or pinhole)",
            key("camera_model")
        ))),
    }
}

/// The native TOML table (serde of [`Camera`]), at top level or under `[camera.intrinsics]`.
fn toml_camera(text: &str, ctx: &Ctx) -> Result<Camera> {
    let one_line =
        |e: toml::de::Error| ctx.err(e.to_string().replace('\n', " ").trim().to_string());
    let table: toml::Table = toml::from_str(text).map_err(one_line)?;
    let value =
        match table.get("camera") {
            Some(toml::Value::Table(cam)) => match cam.get("intrinsics") {
                Some(v) => v.clone(),
                None if cam.contains_key("intrinsics-file") => return Err(ctx.err(
                    "camera.intrinsics-file: this config points to an intrinsics file; pass that \
                     file instead",
                )),
                None => return Err(ctx.err("missing table [camera.intrinsics]")),
            },
            _ => toml::Value::Table(table),
        };
    if let toml::Value::Table(t) = &value {
        if !t.contains_key("model") {
            return Err(ctx.err("missing key model (\"mei\" or \"equidistant\")"));
        }
    }
    value.try_into::<Camera>().map_err(one_line)
}

// ---------------------------------------------------------------------------------------------
// KITTI object-benchmark calibration
// ---------------------------------------------------------------------------------------------

/// The keys of a KITTI object-benchmark calibration file that name its extrinsic (with a `Pn:`
/// line they identify the format).
const KITTI_EXTRINSIC_KEYS: [&str; 2] = ["R0_rect", "Tr_velo_to_cam"];

/// Whether `text` is a KITTI object-benchmark calibration (`calib/NNNNNN.txt`): `key: numbers`
/// lines with a projection `P0:`..`P3:` and `R0_rect:` or `Tr_velo_to_cam:`.
pub fn is_kitti_calib(text: &str) -> bool {
    let keys: Vec<&str> = text
        .lines()
        .filter_map(|l| l.trim_start_matches('\u{feff}').split_once(':'))
        .map(|(k, _)| k.trim())
        .collect();
    keys.iter().any(|k| matches!(*k, "P0" | "P1" | "P2" | "P3"))
        && keys.iter().any(|k| KITTI_EXTRINSIC_KEYS.contains(k))
}

/// A KITTI object-benchmark calibration file (Geiger et al., IJRR 2013; the devkit's
/// `readme.txt`): a Velodyne point `X` projects into rectified camera `i` as
/// `Pi · [R0_rect · (R · X + T); 1]` with `[R | T] = Tr_velo_to_cam`.
#[derive(Debug, Clone, PartialEq)]
pub struct KittiCalib {
    /// The rectified projections present (`P0`..`P3`), 3×4 row-major, in file order.
    pub projections: Vec<(String, [f64; 12])>,
    /// Rectifying rotation of the reference camera, 3×3 row-major.
    pub r0_rect: [f64; 9],
    /// Velodyne → reference camera, 3×4 row-major `[R | T]`.
    pub tr_velo_to_cam: [f64; 12],
}

/// Parse a KITTI object-benchmark calibration. `P0`..`P3`, `R0_rect` and `Tr_velo_to_cam` are read
/// (at least one projection and both of the others are required); other keys (`Tr_imu_to_velo`)
/// are ignored. Errors name the file and the key.
pub fn parse_kitti_calib(text: &str, origin: &Path) -> Result<KittiCalib> {
    let ctx = Ctx { origin };
    let mut projections = Vec::new();
    let (mut r0, mut tr) = (None, None);
    for (ln, line) in text.lines().enumerate() {
        let line = line.trim_start_matches('\u{feff}').trim();
        if line.is_empty() {
            continue;
        }
        let Some((key, rest)) = line.split_once(':') else {
            return Err(ctx.err(format!("line {}: expected KEY: numbers", ln + 1)));
        };
        let key = key.trim();
        let want = match key {
            "P0" | "P1" | "P2" | "P3" | "Tr_velo_to_cam" => 12,
            "R0_rect" => 9,
            _ => continue,
        };
        let values = rest
            .split_whitespace()
            .map(|v| parse_f64(v, key, &ctx))
            .collect::<Result<Vec<f64>>>()?;
        if values.len() != want {
            return Err(ctx.err(format!(
                "{key}: expected {want} numbers, found {}",
                values.len()
            )));
        }
        match key {
            "R0_rect" => r0 = values.try_into().ok(),
            "Tr_velo_to_cam" => tr = values.try_into().ok(),
            _ => {
                if projections.iter().any(|(k, _)| k == key) {
                    return Err(ctx.err(format!("{key}: given twice")));
                }
                if let Ok(p) = values.try_into() {
                    projections.push((key.to_string(), p));
                }
            }
        }
    }
    if projections.is_empty() {
        return Err(ctx.err("missing key P2 (no projection P0..P3)"));
    }
    Ok(KittiCalib {
        projections,
        r0_rect: r0.ok_or_else(|| ctx.err("missing key R0_rect"))?,
        tr_velo_to_cam: tr.ok_or_else(|| ctx.err("missing key Tr_velo_to_cam"))?,
    })
}

impl KittiCalib {
    /// The projection named `name` (`P2` = the left colour camera).
    pub(crate) fn projection(&self, name: &str) -> std::result::Result<&[f64; 12], CameraError> {
        self.projections
            .iter()
            .find(|(k, _)| k == name)
            .map(|(_, p)| p)
            .ok_or_else(|| {
                let have = self.projections.iter().map(|(k, _)| k.clone()).collect();
                CameraError::MissingProjection {
                    name: name.to_string(),
                    have,
                }
            })
    }

    /// `K` of projection `name` = its left 3×3, which must be upper-triangular with K₂₂ = 1 (a
    /// rectified projection `K · [I | b]`), as rows.
    fn k(&self, name: &str) -> std::result::Result<[[f64; 3]; 3], CameraError> {
        let p = self.projection(name)?;
        let k = [[p[0], p[1], p[2]], [p[4], p[5], p[6]], [p[8], p[9], p[10]]];
        if k[1][0] != 0.0 || k[2][0] != 0.0 || k[2][1] != 0.0 || k[2][2] != 1.0 {
            return Err(CameraError::NotRectified {
                name: name.to_string(),
                row2: k[1],
                row3: k[2],
            });
        }
        if !(k[0][0] > 0.0 && k[1][1] > 0.0) {
            return Err(CameraError::ProjectionFocal {
                name: name.to_string(),
                fx: k[0][0],
                fy: k[1][1],
            });
        }
        Ok(k)
    }

    /// Rectified camera `name` as a pinhole: Mei with ξ = 0 and no distortion reproduces
    /// `K · x / x_z` exactly. KITTI's file has no image size: the caller gives it (from the image).
    pub fn camera(
        &self,
        name: &str,
        width: u32,
        height: u32,
    ) -> std::result::Result<Camera, CameraError> {
        let k = self.k(name)?;
        let cam = Camera::Mei(Mei {
            skew: k[0][1],
            ..Mei::pinhole(width, height, k[0][0], k[1][1], k[0][2], k[1][2])
        });
        cam.validate()?;
        Ok(cam)
    }

    /// Velodyne → rectified camera `name` as `(R, t)` with `X_cam = R · X_velo + t`, row-major:
    /// `R = R0_rect · R_velo_to_cam`, `t = R0_rect · T_velo_to_cam + K⁻¹ · Pi[:, 3]` (the fourth
    /// column of a rectified projection is `K · b`, `b` the camera's offset from the reference
    /// camera, so `Pi · [x; 1] = K · (x + b)`). `R` is the product as the file gives it, orthonormal
    /// only to KITTI's printed precision (~1e-7); `crate::pose::CamFromMap::from_rows` projects it
    /// onto a rotation.
    pub fn cam_from_velo(
        &self,
        name: &str,
    ) -> std::result::Result<([[f64; 3]; 3], [f64; 3]), CameraError> {
        use nalgebra::{Matrix3, Vector3};
        let k = self.k(name)?;
        let p = self.projection(name)?;
        let r0 = Matrix3::from_row_slice(&self.r0_rect);
        let tv = &self.tr_velo_to_cam;
        let rv = Matrix3::new(
            tv[0], tv[1], tv[2], tv[4], tv[5], tv[6], tv[8], tv[9], tv[10],
        );
        let t_velo = Vector3::new(tv[3], tv[7], tv[11]);
        let km = Matrix3::from_row_slice(&k.concat());
        let b = km.try_inverse().ok_or_else(|| CameraError::SingularK {
            name: name.to_string(),
        })? * Vector3::new(p[3], p[7], p[11]);
        let r = r0 * rv;
        let t = r0 * t_velo + b;
        // KITTI prints 7 significant digits: a rotation to ~1e-7. Anything far from one is not a
        // calibration (a transposed or mistyped matrix), whatever from_rows would make of it.
        let off = (r.transpose() * r - Matrix3::identity()).norm();
        if !(off < 1e-4 && r.determinant() > 0.0) {
            return Err(CameraError::VeloNotRotation {
                deviation: off,
                det: r.determinant(),
            });
        }
        Ok((
            [
                [r[(0, 0)], r[(0, 1)], r[(0, 2)]],
                [r[(1, 0)], r[(1, 1)], r[(1, 2)]],
                [r[(2, 0)], r[(2, 1)], r[(2, 2)]],
            ],
            [t.x, t.y, t.z],
        ))
    }
}

// ---------------------------------------------------------------------------------------------
// Writing
// ---------------------------------------------------------------------------------------------

/// Shortest round-trip decimal of `v` in exponent form (`4.089e2`). OpenCV's parser treats a
/// number with `e` as real, and strtod reads it back exactly.
fn real(v: f64) -> String {
    format!("{v:e}")
}

fn write_matrix(out: &mut String, key: &str, rows: usize, cols: usize, data: &[f64]) {
    let values: Vec<String> = data.iter().map(|v| real(*v)).collect();
    out.push_str(&format!(
        "{key}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n   data: [ {} ]\n",
        values.join(", ")
    ));
}

/// The camera as an OpenCV FileStorage YAML document (`cv2.FileStorage(path, READ)` reads it; so
/// does [`parse_camera`]): `model`, `image_width`, `image_height`, `camera_matrix`,
/// `distortion_coefficients`, `xi` (Mei only) and `fov_deg` when set.
pub fn to_opencv_yaml(cam: &Camera) -> String {
    let mut out = String::from("%YAML:1.0\n---\n");
    let (model, w, h, k, d, xi, fov) = match cam {
        Camera::Mei(m) => (
            "mei",
            m.width,
            m.height,
            [m.fx, m.skew, m.cx, 0.0, m.fy, m.cy, 0.0, 0.0, 1.0],
            [m.k1, m.k2, m.p1, m.p2],
            Some(m.xi),
            m.fov_deg,
        ),
        Camera::Equidistant(e) => (
            "equidistant",
            e.width,
            e.height,
            [e.fx, e.alpha * e.fx, e.cx, 0.0, e.fy, e.cy, 0.0, 0.0, 1.0],
            [e.k1, e.k2, e.k3, e.k4],
            None,
            e.fov_deg,
        ),
    };
    out.push_str(&format!(
        "model: {model}\nimage_width: {w}\nimage_height: {h}\n"
    ));
    write_matrix(&mut out, "camera_matrix", 3, 3, &k);
    write_matrix(&mut out, "distortion_coefficients", 1, 4, &d);
    if let Some(xi) = xi {
        write_matrix(&mut out, "xi", 1, 1, &[xi]);
    }
    if let Some(f) = fov {
        out.push_str(&format!("fov_deg: {}\n", real(f)));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    const P: &str = "test.yaml";

    #[test]
    fn a_stated_intrinsics_sigma_round_trips_and_bad_values_name_the_key() {
        let cam = Camera::Mei(Mei::pinhole(640, 480, 300.0, 300.0, 320.0, 240.0));
        let plain = to_opencv_yaml(&cam);
        assert_eq!(parse_intrinsics_sigma(&plain, Path::new(P)).unwrap(), None);
        let s = IntrinsicsSigma {
            focal_rel: 0.002,
            principal_point_px: 1.5,
        };
        let text = format!("{plain}{}", s.yaml_lines());
        assert_eq!(
            parse_intrinsics_sigma(&text, Path::new(P)).unwrap(),
            Some(s)
        );
        // The camera itself still parses from the same file.
        assert_eq!(parse(&text).unwrap(), cam);
        // Three 1σ modes: the focal scale moves fx and fy together, then cx, then cy.
        let m = s.perturbed(&cam);
        assert_eq!(m.len(), 3);
        let Camera::Mei(f) = &m[0] else {
            unreachable!()
        };
        assert!((f.fx - 300.6).abs() < 1e-9 && (f.fy - 300.6).abs() < 1e-9 && f.cx == 320.0);
        let Camera::Mei(c) = &m[2] else {
            unreachable!()
        };
        assert!(c.cy == 241.5 && c.cx == 320.0 && c.fx == 300.0);
        for bad in [
            "sigma_focal_rel: -0.1\n",
            "sigma_principal_point_px: .nan\n",
            "sigma_focal_rel: 0.7\n",
        ] {
            let e = parse_intrinsics_sigma(&format!("{plain}{bad}"), Path::new(P))
                .expect_err(bad)
                .to_string();
            let key = bad.split(':').next().unwrap_or_default();
            assert!(e.contains(P) && e.contains(key), "{bad}: {e}");
        }
    }

    fn parse(text: &str) -> Result<Camera> {
        parse_camera(text, Path::new(P))
    }

    fn err(text: &str) -> String {
        parse(text).unwrap_err().to_string()
    }

    const OPENCV_YAML: &str = "%YAML:1.0
---
image_width: 1280
image_height: 960
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 408.89999999999998, -0.63, 630.20000000000005, 0.,
       410.39999999999998, 431.89999999999998, 0., 0., 1. ]
xi: !!opencv-matrix
   rows: 1
   cols: 1
   dt: d
   data: [ 1.0533861712345678 ]
distortion_coefficients: !!opencv-matrix
   rows: 1
   cols: 4
   dt: d
   data: [ -0.0083000000000000001, 0.0117, 0.022800000000000001,
       -0.0041000000000000003 ]
";

    #[test]
    fn opencv_yaml_mei() {
        let Camera::Mei(m) = parse(OPENCV_YAML).unwrap() else {
            panic!("not mei")
        };
        assert_eq!((m.width, m.height), (1280, 960));
        assert_eq!((m.fx, m.skew, m.cx), (408.9, -0.63, 630.2));
        assert_eq!((m.fy, m.cy, m.xi), (410.4, 431.9, 1.0533861712345678));
        assert_eq!([m.k1, m.k2, m.p1, m.p2], [-0.0083, 0.0117, 0.0228, -0.0041]);
    }

    #[test]
    fn opencv_yaml_errors_name_the_key() {
        let e = err(&OPENCV_YAML.replace("image_width: 1280\n", ""));
        assert!(e.starts_with("test.yaml: missing key image_width"), "{e}");
        let e = err(&OPENCV_YAML.replace("   rows: 3\n", "   rows: 2\n"));
        assert!(
            e.contains("camera_matrix: declared 2×3 but data holds 9"),
            "{e}"
        );
        let e = err(&OPENCV_YAML.replace("0.0117,", "0.0117, 0.5,"));
        assert!(
            e.contains("distortion_coefficients: declared 1×4 but data holds 5"),
            "{e}"
        );
        let e = err(&OPENCV_YAML.replace("1.0533861712345678", "abc"));
        assert!(e.contains("xi.data: \"abc\""), "{e}");
        let e = err(&OPENCV_YAML.replace("xi:", "xj:"));
        assert!(e.ends_with("missing key xi"), "{e}");
        let e = err(&format!("{OPENCV_YAML}model: scaramuzza\n"));
        assert!(e.contains("model: \"scaramuzza\" is not supported"), "{e}");
        assert!(!e.contains('\n'));
    }

    #[test]
    fn opencv_xml_equals_yaml() {
        let xml = r#"<?xml version="1.0"?>
<opencv_storage>
<image_width>1280</image_width>
<image_height>960</image_height>
<camera_matrix type_id="opencv-matrix">
  <rows>3</rows>
  <cols>3</cols>
  <dt>d</dt>
  <data>
    408.89999999999998 -0.63 630.20000000000005 0. 410.39999999999998
    431.89999999999998 0. 0. 1.</data></camera_matrix>
<xi>1.0533861712345678</xi>
<distortion_coefficients type_id="opencv-matrix">
  <rows>4</rows>
  <cols>1</cols>
  <dt>"d"</dt>
  <data>
    -0.0083000000000000001 0.0117 0.022800000000000001
    -0.0041000000000000003</data></distortion_coefficients>
</opencv_storage>
"#;
        assert_eq!(parse(xml).unwrap(), parse(OPENCV_YAML).unwrap());
        let e = err(&xml.replace("<rows>4</rows>", "<rows>2</rows><cols>2</cols>"));
        assert!(!e.is_empty());
    }

    #[test]
    fn opencv_equidistant_alpha_from_skew() {
        let text = OPENCV_YAML
            .replace("xi: !!opencv-matrix\n   rows: 1\n   cols: 1\n   dt: d\n   data: [ 1.0533861712345678 ]\n", "")
            + "model: equidistant\nfov_deg: 185\n";
        let Camera::Equidistant(e) = parse(&text).unwrap() else {
            panic!("not equidistant")
        };
        assert_eq!(e.alpha, -0.63 / 408.9);
        assert_eq!([e.k1, e.k2, e.k3, e.k4], [-0.0083, 0.0117, 0.0228, -0.0041]);
        assert_eq!(e.fov_deg, Some(185.0));
    }

    const KALIBR: &str = "cam0:
  cam_overlaps: [1]
  camera_model: omni
  distortion_coeffs: [-0.1, 0.02, 0.001, -0.002]
  distortion_model: radtan
  intrinsics: [0.9, 500.0, 501.0, 640.5, 480.5]
  resolution: [1280, 960]
  rostopic: /cam0/image_raw
cam1:
  T_cn_cnm1:
  - [1.0, 0.0, 0.0, 0.1]
  - [0.0, 1.0, 0.0, 0.0]
  - [0.0, 0.0, 1.0, 0.0]
  - [0.0, 0.0, 0.0, 1.0]
  camera_model: pinhole
  distortion_coeffs: [0.01, -0.002, 0.0003, -0.00004]
  distortion_model: equidistant
  intrinsics: [300.0, 301.0, 320.0, 240.0]
  resolution: [640, 480]
";

    #[test]
    fn kalibr_first_and_named() {
        let Camera::Mei(m) = parse(KALIBR).unwrap() else {
            panic!()
        };
        assert_eq!(
            (m.xi, m.fx, m.fy, m.cx, m.cy),
            (0.9, 500.0, 501.0, 640.5, 480.5)
        );
        assert_eq!([m.k1, m.k2, m.p1, m.p2], [-0.1, 0.02, 0.001, -0.002]);
        let c = parse_camera_named(KALIBR, Path::new(P), Some("cam1")).unwrap();
        let Camera::Equidistant(e) = c else { panic!() };
        assert_eq!((e.width, e.fx, e.k4), (640, 300.0, -0.00004));
        let e = parse_camera_named(KALIBR, Path::new(P), Some("cam7"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("\"cam7\" not in camchain (has cam0, cam1)"),
            "{e}"
        );
        let e = err(&KALIBR.replace("camera_model: omni", "camera_model: ds"));
        assert!(
            e.contains("cam0.camera_model: \"ds\" is not supported"),
            "{e}"
        );
        let e = err(&KALIBR.replace("  resolution: [1280, 960]\n", ""));
        assert!(e.ends_with("missing key cam0.resolution"), "{e}");
        let e = err(&KALIBR.replace("640.5, 480.5]", "640.5]"));
        assert!(
            e.contains("cam0.intrinsics: camera_model omni needs 5"),
            "{e}"
        );
    }

    #[test]
    fn kalibr_pinhole_radtan_is_mei_xi_0() {
        let t = KALIBR
            .replace("camera_model: omni", "camera_model: pinhole")
            .replace(
                "[0.9, 500.0, 501.0, 640.5, 480.5]",
                "[500.0, 501.0, 640.5, 480.5]",
            );
        let Camera::Mei(m) = parse(&t).unwrap() else {
            panic!()
        };
        assert_eq!((m.xi, m.fx, m.cy), (0.0, 500.0, 480.5));
    }

    const KITTI: &str = "%YAML:1.0
---
model_type: MEI
camera_name: image_02
image_width: 1400
image_height: 1400
mirror_parameters:
   xi: 2.2134
distortion_parameters:
   k1: 0.0168
   k2: 1.6549
   p1: 4.22e-4
   p2: 4.25e-4
projection_parameters:
   gamma1: 1336.32
   gamma2: 1335.79
   u0: 716.94
   v0: 705.76
";

    #[test]
    fn kitti360_mei() {
        let Camera::Mei(m) = parse(KITTI).unwrap() else {
            panic!()
        };
        assert_eq!(
            (m.xi, m.k1, m.k2, m.p1, m.p2),
            (2.2134, 0.0168, 1.6549, 4.22e-4, 4.25e-4)
        );
        assert_eq!((m.fx, m.fy, m.cx, m.cy), (1336.32, 1335.79, 716.94, 705.76));
        let e = err(&KITTI.replace("   p2: 4.25e-4\n", ""));
        assert!(e.ends_with("missing key distortion_parameters.p2"), "{e}");
        let e = err(&KITTI.replace("MEI", "KANNALA_BRANDT"));
        assert!(e.contains("model_type: \"KANNALA_BRANDT\""), "{e}");
    }

    #[test]
    fn toml_top_level_and_config_table() {
        let body = "model = \"mei\"\nwidth = 1400\nheight = 1400\nfx = 1336.32\nfy = 1335.79\n\
                    cx = 716.94\ncy = 705.76\nxi = 2.2134\nk1 = 0.0168\nk2 = 1.6549\n\
                    p1 = 4.22e-4\np2 = 4.25e-4\n";
        let a = parse(body).unwrap();
        let b = parse(&format!(
            "[camera]\nsource = \"file\"\n[camera.intrinsics]\n{body}"
        ))
        .unwrap();
        assert_eq!(a, b);
        assert_eq!(a, parse(KITTI).unwrap());
        let e = err(&body.replace("xi = 2.2134\n", ""));
        assert!(e.contains("xi"), "{e}");
        assert!(!e.contains('\n'), "{e}");
        let e = err(&body.replace("\"mei\"", "\"scaramuzza\""));
        assert!(e.contains("scaramuzza"), "{e}");
    }

    #[test]
    fn unrecognised_and_invalid_values() {
        let e = err("foo: 1\nbar: 2\n");
        assert!(e.contains("unrecognised intrinsics YAML"), "{e}");
        let e = err(&KITTI.replace("gamma1: 1336.32", "gamma1: -5"));
        assert!(e.contains("fx"), "{e}");
        let e = parse_camera_named(KITTI, Path::new(P), Some("cam1")).unwrap_err();
        assert!(e.to_string().contains("one camera"));
    }

    /// A KITTI-style calibration with every term non-trivial: a skewed K, a baseline with a
    /// z component in P2's fourth column, a rectifying rotation and a Velodyne extrinsic.
    const KITTI_CALIB: &str = "P0: 700 0 600 0 0 710 180 0 0 0 1 0
P2: 7.0e2 0.5 6.0e2 45.0 0 7.1e2 1.8e2 -0.35 0 0 1 0.005
R0_rect: 0.9999128 0.01009263 -0.008511932 -0.01012729 0.9999406 -0.004037671 0.008470675 0.004123522 0.9999556
Tr_velo_to_cam: 0 -1 0 -0.02 0 0 -1 -0.06 1 0 0 -0.33
Tr_imu_to_velo: 1 0 0 0 0 1 0 0 0 0 1 0
";

    #[test]
    fn kitti_calib_pinhole_and_extrinsic_reproduce_the_kitti_projection() {
        use crate::camera::CameraModel;
        assert!(is_kitti_calib(KITTI_CALIB));
        let c = parse_kitti_calib(KITTI_CALIB, Path::new("calib.txt")).unwrap();
        let cam = c.camera("P2", 1242, 375).unwrap();
        let (r, t) = c.cam_from_velo("P2").unwrap();
        let p2 = c.projection("P2").unwrap();
        let (r0, tr) = (&c.r0_rect, &c.tr_velo_to_cam);
        // KITTI's formula written out element by element: P2 · [R0 · (R·X + T); 1].
        let kitti = |x: [f64; 3]| {
            let v: Vec<f64> = (0..3)
                .map(|i| {
                    tr[4 * i] * x[0] + tr[4 * i + 1] * x[1] + tr[4 * i + 2] * x[2] + tr[4 * i + 3]
                })
                .collect();
            let w: Vec<f64> = (0..3)
                .map(|i| r0[3 * i] * v[0] + r0[3 * i + 1] * v[1] + r0[3 * i + 2] * v[2])
                .collect();
            let h: Vec<f64> = (0..3)
                .map(|i| {
                    p2[4 * i] * w[0] + p2[4 * i + 1] * w[1] + p2[4 * i + 2] * w[2] + p2[4 * i + 3]
                })
                .collect();
            (h[0] / h[2], h[1] / h[2])
        };
        for x in [
            [10.0, 2.0, -1.5],
            [25.0, -6.0, 0.5],
            [5.5, 0.3, -1.7],
            [60.0, 12.0, 3.0],
        ] {
            let xc = nalgebra::Vector3::from_fn(|i, _| {
                r[i][0] * x[0] + r[i][1] * x[1] + r[i][2] * x[2] + t[i]
            });
            let px = cam.project(&xc).unwrap();
            let (u, v) = kitti(x);
            assert!(
                (px.x - u).abs() < 1e-9 && (px.y - v).abs() < 1e-9,
                "{px:?} vs ({u}, {v})"
            );
        }
        // The Mei table: ξ = 0, no distortion, K's skew kept.
        let Camera::Mei(m) = &cam else {
            panic!("{cam:?}")
        };
        assert_eq!(
            (m.xi, m.k1, m.k2, m.p1, m.p2, m.skew),
            (0.0, 0.0, 0.0, 0.0, 0.0, 0.5)
        );
        assert_eq!((m.width, m.height, m.fx, m.cy), (1242, 375, 700.0, 180.0));
    }

    #[test]
    fn kitti_calib_errors_name_the_file_and_key() {
        let o = Path::new("calib.txt");
        let e = |t: &str| parse_kitti_calib(t, o).unwrap_err().to_string();
        assert!(e(&KITTI_CALIB.replace("R0_rect", "R9_rect")).contains("missing key R0_rect"));
        assert!(
            e(&KITTI_CALIB.replace("Tr_velo_to_cam: 0 -1", "Tr_velo_to_cam: -1"))
                .contains("Tr_velo_to_cam: expected 12 numbers, found 11")
        );
        let nan = e(&KITTI_CALIB.replace("7.1e2", "nan"));
        assert!(
            nan.starts_with("calib.txt: P2:") && nan.contains("not a finite number"),
            "{nan}"
        );
        let c = parse_kitti_calib(KITTI_CALIB, o).unwrap();
        assert!(c
            .camera("P3", 10, 10)
            .unwrap_err()
            .to_string()
            .contains("missing key P3 (has P0, P2)"));
        // A transposed extrinsic with a scale error is not a rotation.
        let bad = parse_kitti_calib(
            &KITTI_CALIB.replace("Tr_velo_to_cam: 0 -1 0", "Tr_velo_to_cam: 0 -2 0"),
            o,
        )
        .unwrap();
        assert!(bad
            .cam_from_velo("P2")
            .unwrap_err()
            .to_string()
            .contains("not a rotation"));
        // The camera loader recognises the format and says how to make a camera file of it.
        let l = parse_camera(KITTI_CALIB, o).unwrap_err().to_string();
        assert!(
            l.starts_with("calib.txt: a KITTI calibration") && l.contains("kitti import"),
            "{l}"
        );
        assert!(!is_kitti_calib(
            "%YAML:1.0\ncamera_matrix: !!opencv-matrix\n"
        ));
    }

    #[test]
    fn opencv_yaml_round_trip() {
        for text in [OPENCV_YAML.to_string(), KITTI.to_string()] {
            let cam = parse(&text).unwrap();
            assert_eq!(parse(&to_opencv_yaml(&cam)).unwrap(), cam);
        }
        let mut e = match parse(KALIBR).unwrap() {
            Camera::Mei(_) => parse_camera_named(KALIBR, Path::new(P), Some("cam1")).unwrap(),
            c => c,
        };
        if let Camera::Equidistant(ref mut q) = e {
            // A power of two, so K[0][1] = α·fx divides back exactly.
            q.alpha = 0.015625;
            q.fov_deg = Some(185.0);
        }
        assert_eq!(parse(&to_opencv_yaml(&e)).unwrap(), e);
    }
}
