//! The initialization's matcher seam: anything that pairs fisheye pixels with map points can
//! stand in for the built-in satellite matching (the dense orientation sweep and the patch
//! stages of [`crate::localize::init`]), and PnP + RANSAC on bearings then makes the pose.
//!
//! The seed used a learned matcher (SuperGlue). No weights can be fetched here and the node needs
//! no network, so the default stays learning-free; a learned matcher plugs in as one more
//! [`Matcher`], built by the shell from the configured `matcher-path` (its weights) the way
//! [`MatchFile`] is built from its correspondence file. The trait is pure: the shell reads the
//! file, the matcher sees only the frame and the map around the prior.

use crate::camera::CameraModel;
use crate::error::{Error, Result};
use crate::localize::error::MatchFileError;
use crate::localize::init::ground::height_at;
use crate::localize::init::sweep::Candidate;
use crate::localize::init::verify::MiVerifier;
use crate::localize::init::{FineParams, InitResult};
use crate::localize::pnp::{solve_pnp_ransac, Correspondence, PnpParams};
use crate::map::Raster;
use crate::stage::StageName;
use nalgebra::{Point2, Point3};

/// What a matcher sees: the (temporally median-filtered) fisheye frame with its camera, and the
/// tile's satellite image and height layer around the GPS prior.
pub struct MatchQuery<'a> {
    /// The frame's camera.
    pub camera: &'a dyn CameraModel,
    /// Gray frame, row-major, `camera.width() × camera.height()`.
    pub image: &'a [u8],
    /// The tile's satellite image (map CRS).
    pub satellite: &'a Raster<[u8; 3]>,
    /// The tile's ground height layer (map CRS), metres.
    pub heights: &'a Raster<f32>,
    /// GPS prior, map CRS (east, north), metres.
    pub prior_xy: (f64, f64),
    /// The camera lies within this distance of the prior, metres.
    pub search_radius_m: f64,
}

/// A source of correspondences between the fisheye frame and the map for the initialization's
/// PnP. Pixels are in the fisheye frame as captured (not rectified: PnP works on bearings, so
/// every ray of the 185° field is usable), map points in the tile's CRS. Outliers are expected:
/// RANSAC sorts them.
pub trait Matcher: Send + Sync + std::fmt::Debug {
    /// Name for reports and error messages.
    fn name(&self) -> &str;
    /// The correspondences for this query; an error names what is missing.
    fn correspondences(&self, q: &MatchQuery<'_>) -> Result<Vec<Correspondence>>;
    /// The file the matcher was built from (its correspondences or weights), named in errors.
    fn origin(&self) -> Option<&std::path::Path> {
        None
    }
}

/// One row of a [`MatchFile`]: a fisheye pixel and the map point it shows; without `z` the
/// point lies on the ground (height layer).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatchRow {
    /// Fisheye pixel (column, row), pixel centres at integers.
    pub pixel: Point2<f64>,
    /// Map CRS easting, northing, metres.
    pub map_xy: (f64, f64),
    /// Map height, metres; `None` = the height layer's ground at `map_xy`.
    pub z: Option<f64>,
}

/// Correspondences made elsewhere and handed over in a file: a learned matcher run offline on
/// the node's frame, or surveyed marks picked in the image. CSV with a header naming the columns
/// `u`, `v` (fisheye pixel), `x`, `y` (map CRS) and optionally `z`, in any order.
///
/// PnP needs at least `crate::localize::pnp::PnpParams::min_inliers` (12) rows that agree: a handful of
/// surveyed marks is too few on its own. The file is fixed: after the camera is knocked, its
/// pixels no longer match and the drift check's re-localization fails until it is remade.
#[derive(Debug, Clone, PartialEq)]
pub struct MatchFile {
    rows: Vec<MatchRow>,
    /// Where the rows came from, for error messages.
    origin: std::path::PathBuf,
}

impl MatchFile {
    /// Parse the CSV text read from `origin` (named in later errors); errors name the line and
    /// the column. A leading byte-order mark (spreadsheet exports) is skipped.
    pub fn parse(
        text: &str,
        origin: &std::path::Path,
    ) -> std::result::Result<MatchFile, MatchFileError> {
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        let mut lines = text
            .lines()
            .enumerate()
            .filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'));
        let (_, header) = lines.next().ok_or(MatchFileError::NoHeader)?;
        let cols: Vec<String> = header
            .split(',')
            .map(|c| c.trim().trim_matches('"').to_ascii_lowercase())
            .collect();
        let find = |name: &str| cols.iter().position(|c| c == name);
        let need = |name: &'static str| {
            find(name).ok_or_else(|| MatchFileError::NoColumn {
                header: header.to_string(),
                column: name,
            })
        };
        let (iu, iv, ix, iy) = (need("u")?, need("v")?, need("x")?, need("y")?);
        let iz = find("z");
        let mut rows = Vec::new();
        for (ln, line) in lines {
            let f: Vec<&str> = line.split(',').map(str::trim).collect();
            let line = ln + 1;
            let get =
                |i: usize, column: &'static str| -> std::result::Result<f64, MatchFileError> {
                    let v: f64 = f
                        .get(i)
                        .ok_or(MatchFileError::Missing { line, column })?
                        .parse()
                        .map_err(|_| MatchFileError::NotANumber { line, column })?;
                    if v.is_finite() {
                        Ok(v)
                    } else {
                        Err(MatchFileError::NotFinite { line, column })
                    }
                };
            // An empty z cell means "on the ground", like a file without the column.
            let z = match iz {
                Some(i) if f.get(i).is_some_and(|s| !s.is_empty()) => Some(get(i, "z")?),
                _ => None,
            };
            rows.push(MatchRow {
                pixel: Point2::new(get(iu, "u")?, get(iv, "v")?),
                map_xy: (get(ix, "x")?, get(iy, "y")?),
                z,
            });
        }
        if rows.is_empty() {
            return Err(MatchFileError::Empty);
        }
        Ok(MatchFile {
            rows,
            origin: origin.to_path_buf(),
        })
    }

    /// The rows as read.
    pub fn rows(&self) -> &[MatchRow] {
        &self.rows
    }
}

impl Matcher for MatchFile {
    fn name(&self) -> &str {
        "match-file"
    }

    fn origin(&self) -> Option<&std::path::Path> {
        Some(&self.origin)
    }

    /// The rows whose pixel lies on the image and whose map point lies within the search radius
    /// plus `MAX_GROUND_REACH_M` of the prior (rows far outside belong to another site); a row
    /// without `z` takes the height layer's ground, and is dropped where the layer has no data.
    fn correspondences(&self, q: &MatchQuery<'_>) -> Result<Vec<Correspondence>> {
        let (w, h) = (q.camera.width() as f64, q.camera.height() as f64);
        let reach = q.search_radius_m + MAX_GROUND_REACH_M;
        let out: Vec<Correspondence> = self
            .rows
            .iter()
            .filter(|r| {
                (-0.5..w - 0.5).contains(&r.pixel.x)
                    && (-0.5..h - 0.5).contains(&r.pixel.y)
                    && (r.map_xy.0 - q.prior_xy.0).hypot(r.map_xy.1 - q.prior_xy.1) <= reach
            })
            .filter_map(|r| {
                let z =
                    r.z.or_else(|| height_at(q.heights, r.map_xy.0, r.map_xy.1))?;
                Some(Correspondence {
                    pixel: r.pixel,
                    world: Point3::new(r.map_xy.0, r.map_xy.1, z),
                })
            })
            .collect();
        if out.is_empty() {
            return Err(Error::stage(
                StageName::Pnp,
                format!(
                    "match-file {}: none of its {} rows lies on the image and within {reach:.0} m of the prior with a height",
                    self.origin.display(),
                    self.rows.len()
                ),
            ));
        }
        Ok(out)
    }
}

/// A row's map point may lie this far beyond the search radius around the prior, metres: ground
/// the camera can usefully see (the fine stages' anchors stop at 25 m from the nadir point), with
/// room to spare; rows farther out belong to another site.
pub(crate) const MAX_GROUND_REACH_M: f64 = 60.0;

/// Initialization with a [`Matcher`]: its correspondences, then PnP + RANSAC on bearings (the
/// fine stages' PnP settings, a [`MATCHER_THRESHOLD_PX`] threshold) and Levenberg–Marquardt on
/// the inliers. The built-in patch stages do not follow: from the `tests/matcher.rs` scene's
/// sub-pixel correspondences they took the pose from 5 cm to 33 cm off (their 0.1 m patches on
/// `hard`'s wrong intrinsics are coarser than a good matcher), and the MI refinement that follows
/// already converges from a metre. With a verifier the pose's MI with the LiDAR map is reported
/// as the built-in path does. Errors name the stage and the numbers.
pub(crate) fn initialize_with<R: rand::Rng>(
    matcher: &dyn Matcher,
    q: &MatchQuery<'_>,
    fine: &FineParams,
    verifier: Option<&MiVerifier>,
    rng: &mut R,
) -> Result<InitResult> {
    let corr = matcher.correspondences(q)?;
    let params = PnpParams {
        threshold_px: MATCHER_THRESHOLD_PX,
        ..fine.pnp
    };
    let r = solve_pnp_ransac(q.camera, &corr, &params, rng).map_err(|e| {
        // The solver's own error already says `pnp: …`; one stage prefix is enough.
        let why = match e {
            Error::Stage {
                stage: StageName::Pnp,
                msg,
            } => msg,
            other => other.to_string(),
        };
        let from = matcher
            .origin()
            .map(|p| format!(" {}", p.display()))
            .unwrap_or_default();
        Error::stage(StageName::Pnp, format!("{}{from}: {why}", matcher.name()))
    })?;
    let pose = r.pose;
    let c = pose.center();
    let ground = height_at(q.heights, c.x, c.y).unwrap_or(0.0);
    let mi = verifier.and_then(|v| v.verify(&pose)).map(|v| (v.mi, None));
    Ok(InitResult {
        pose,
        candidate: Candidate {
            yaw: pose.yaw_pitch_roll().0,
            height: c.z - ground,
            offset: [c.x - q.prior_xy.0, c.y - q.prior_xy.1],
            score: f64::NAN,
        },
        matches: corr.len(),
        inliers: r.inliers.len(),
        rms_px: r.rms_px,
        tilt_sigma_deg: r.tilt_sigma_deg,
        covariance: r.covariance,
        candidates_tried: 1,
        candidate_rank: 0,
        mi,
        partial_fine_stage: false,
        runner_up: None,
    })
}

/// RANSAC inlier threshold for a matcher's correspondences, pixels: a learned matcher's keypoints
/// are pixel-accurate at best, and a handed-over file may come from a rectified view.
pub(crate) const MATCHER_THRESHOLD_PX: f64 = 4.0;

#[cfg(test)]
mod tests {
    use super::*;

    fn o() -> &'static std::path::Path {
        std::path::Path::new("m.csv")
    }

    #[test]
    fn match_file_columns_in_any_order_with_optional_z() {
        let m = MatchFile::parse(
            "\u{feff}# made offline\nx, Y ,u,v,z\n10,20,1.5,2.5,3\n\n11,21,4,5,\n",
            o(),
        )
        .unwrap();
        assert_eq!(
            m.rows(),
            &[
                MatchRow {
                    pixel: Point2::new(1.5, 2.5),
                    map_xy: (10.0, 20.0),
                    z: Some(3.0),
                },
                MatchRow {
                    pixel: Point2::new(4.0, 5.0),
                    map_xy: (11.0, 21.0),
                    z: None,
                },
            ]
        );
        let no_z = MatchFile::parse("\u{feff}u,v,x,y\n1,2,3,4\n", o()).unwrap();
        assert_eq!(no_z.rows()[0].z, None);
    }

    #[test]
    fn match_file_errors_name_the_line_and_column() {
        let e = |t: &str| MatchFile::parse(t, o()).unwrap_err().to_string();
        assert!(e("").contains("no header"), "{}", e(""));
        assert!(e("u,v,x\n1,2,3\n").contains("no column \"y\""));
        assert!(e("u,v,x,y\n").contains("no correspondences"));
        assert_eq!(
            e("u,v,x,y\n1,2,3,4\n1,b,3,4\n"),
            "line 3: v is not a number"
        );
        assert_eq!(e("u,v,x,y\n1,2,3\n"), "line 2: missing y");
        assert_eq!(e("u,v,x,y\n1,2,inf,4\n"), "line 2: x is not finite");
    }
}
