//! The mutual-information estimator (pure): binning, joint histogram → MI / NMI.
//!
//! X = reflectivity bin (histogram row), Y = gray bin (column). The joint histogram has one extra
//! column, `JointHist::invalid_col`, which collects points that do not land on a valid pixel; it
//! is excluded from every probability, so a point either counts fully or not at all.
//!
//! Defaults (see `docs/refine.md` for the measurements): 32 × 32 bins with histogram-equalised
//! (quantile) bin edges, binomial Parzen smoothing of the joint histogram, MI objective on a fixed
//! point set (the bias remedy, see [`crate::localize::refine::search`]).

pub mod kernel;
pub mod objective;
pub mod points;
pub mod smooth;
pub mod space;

use crate::error::{Error, Result};
use crate::localize::error::LocalizeError;
use serde::{Deserialize, Serialize};

/// Largest number of gray bins: gray bins are stored as u8 and one value is the invalid marker.
pub const MAX_GRAY_BINS: usize = 255;
/// Largest number of reflectivity bins.
pub const MAX_REFLECTIVITY_BINS: usize = 256;

/// Which statistic the search maximises.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum Objective {
    /// MI = H(X) + H(Y) − H(X,Y) (the seed's).
    #[default]
    Mi,
    /// Normalised MI (Studholme): (H(X) + H(Y)) / H(X,Y).
    Nmi,
}

impl Objective {
    /// The name used on the command line and in reports (`mi`, `nmi`).
    pub(crate) fn name(self) -> &'static str {
        match self {
            Objective::Mi => "mi",
            Objective::Nmi => "nmi",
        }
    }
}

impl std::fmt::Display for Objective {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Objective {
    type Err = Error;
    /// `mi` or `nmi`; anything else is a one-line error naming `--objective` (the CLI's flag).
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "mi" => Ok(Objective::Mi),
            "nmi" => Ok(Objective::Nmi),
            _ => Err(choice("objective", s, "mi or nmi")),
        }
    }
}

/// A `--FLAG` choice outside its set, as the crate's error.
pub(crate) fn choice(flag: &'static str, given: &str, expected: &'static str) -> Error {
    LocalizeError::Choice {
        flag,
        given: given.to_string(),
        expected,
    }
    .into()
}

/// How 0–255 values map to bins.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum Binning {
    /// Equal-width bins over 0–255.
    Uniform,
    /// Quantile bins from the data's own histogram (histogram equalisation): every bin is used about
    /// equally, whatever the exposure or the LiDAR's reflectivity calibration.
    #[default]
    Equalized,
}

impl Binning {
    /// The name used on the command line and in reports (`uniform`, `equalized`).
    pub(crate) fn name(self) -> &'static str {
        match self {
            Binning::Uniform => "uniform",
            Binning::Equalized => "equalized",
        }
    }
}

impl std::fmt::Display for Binning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Binning {
    type Err = Error;
    /// `uniform` or `equalized`; anything else is a one-line error naming `--binning`.
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "uniform" => Ok(Binning::Uniform),
            "equalized" => Ok(Binning::Equalized),
            _ => Err(choice("binning", s, "equalized or uniform")),
        }
    }
}

/// How several image/point-set pairs are pooled into one objective.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum Pooling {
    /// One joint histogram summed over the pairs.
    #[default]
    Joint,
    /// One histogram per pair; the objective is the point-weighted sum of the pairs' MI.
    PerPair,
}

impl Pooling {
    /// The command-line name (`joint`, `per-pair`).
    pub fn name(self) -> &'static str {
        match self {
            Pooling::Joint => "joint",
            Pooling::PerPair => "per-pair",
        }
    }
}

impl std::fmt::Display for Pooling {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Pooling {
    type Err = Error;
    /// `joint` or `per-pair`; anything else is a one-line error naming `--pooling`.
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "joint" => Ok(Pooling::Joint),
            "per-pair" => Ok(Pooling::PerPair),
            _ => Err(choice("pooling", s, "joint or per-pair")),
        }
    }
}

/// Estimator settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", deny_unknown_fields, default)]
pub struct MiConfig {
    /// Reflectivity bins (2..=256).
    pub bins_reflectivity: usize,
    /// Gray bins (2..=255).
    pub bins_gray: usize,
    /// Bin-edge rule, applied to both variables.
    pub binning: Binning,
    /// Statistic maximised by the search.
    pub objective: Objective,
    /// Parzen smoothing: convolve the joint histogram with a 3×3 binomial kernel before the
    /// entropies (reduces the small-sample noise of sparse cells).
    pub parzen: bool,
    /// With several image/point-set pairs: one joint histogram of all of them, or one per pair
    /// ([`pooled_information`]). One pair is the same either way.
    pub pooling: Pooling,
}

impl Default for MiConfig {
    fn default() -> Self {
        MiConfig {
            bins_reflectivity: 32,
            bins_gray: 32,
            binning: Binning::Equalized,
            objective: Objective::Mi,
            parzen: true,
            pooling: Pooling::Joint,
        }
    }
}

impl MiConfig {
    /// Check the bin counts.
    pub fn validate(&self) -> Result<()> {
        if !(2..=MAX_REFLECTIVITY_BINS).contains(&self.bins_reflectivity) {
            return Err(LocalizeError::Bins {
                what: "bins-reflectivity",
                bins: self.bins_reflectivity,
                max: MAX_REFLECTIVITY_BINS,
            }
            .into());
        }
        if !(2..=MAX_GRAY_BINS).contains(&self.bins_gray) {
            return Err(LocalizeError::Bins {
                what: "bins-gray",
                bins: self.bins_gray,
                max: MAX_GRAY_BINS,
            }
            .into());
        }
        Ok(())
    }
}

/// Value → bin lookup table for 0–255 data. `counts` is the data's 256-entry histogram (only
/// used for [`Binning::Equalized`]).
pub fn bin_lut(binning: Binning, bins: usize, counts: &[u64; 256]) -> [u8; 256] {
    let bins = bins.clamp(1, 256);
    let mut lut = [0u8; 256];
    match binning {
        Binning::Uniform => {
            for (v, l) in lut.iter_mut().enumerate() {
                *l = (v * bins / 256) as u8;
            }
        }
        Binning::Equalized => {
            let total: u64 = counts.iter().sum();
            if total == 0 {
                return bin_lut(Binning::Uniform, bins, counts);
            }
            // Bin of value v = floor(bins · CDF_mid(v)), the mid-point CDF so a value holding
            // much of the mass sits in the middle of the bins it spans rather than at its edge.
            let mut below = 0u64;
            for (v, l) in lut.iter_mut().enumerate() {
                let mid = below as f64 + 0.5 * counts[v] as f64;
                let b = (mid / total as f64 * bins as f64) as usize;
                *l = b.min(bins - 1) as u8;
                below += counts[v];
            }
        }
    }
    lut
}

/// A joint histogram of `rows` reflectivity bins × (`cols` gray bins + 1 invalid column), u32
/// counts, row-major with stride `cols + 1`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct JointHist {
    /// Reflectivity bins.
    pub rows: usize,
    /// Gray bins (valid ones).
    pub cols: usize,
    /// Counts, `rows × (cols + 1)`.
    pub counts: Vec<u32>,
}

impl JointHist {
    /// An all-zero histogram.
    pub fn new(rows: usize, cols: usize) -> Self {
        JointHist {
            rows,
            cols,
            counts: vec![0; rows * (cols + 1)],
        }
    }

    /// Add `other`'s counts (same shape) to this histogram's.
    pub(crate) fn add(&mut self, other: &JointHist) {
        self.counts
            .iter_mut()
            .zip(&other.counts)
            .for_each(|(a, b)| *a += b);
    }

    /// Row stride of `counts`.
    #[inline]
    pub fn stride(&self) -> usize {
        self.cols + 1
    }

    /// Index of the column that collects points without a valid pixel.
    #[inline]
    pub(crate) fn invalid_col(&self) -> usize {
        self.cols
    }

    /// Points that landed on a valid pixel.
    pub(crate) fn valid_count(&self) -> u64 {
        let s = self.stride();
        (0..self.rows)
            .map(|r| {
                self.counts[r * s..r * s + self.cols]
                    .iter()
                    .map(|&c| c as u64)
                    .sum::<u64>()
            })
            .sum()
    }

    /// Points that did not.
    pub(crate) fn invalid_count(&self) -> u64 {
        let s = self.stride();
        (0..self.rows)
            .map(|r| self.counts[r * s + self.cols] as u64)
            .sum()
    }
}

/// MI statistics of one joint histogram (natural log, nats).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MiValue {
    /// H(X) + H(Y) − H(X,Y).
    pub mi: f64,
    /// (H(X) + H(Y)) / H(X,Y); 1 when independent, 2 when one determines the other.
    pub nmi: f64,
    /// Points that counted.
    pub n: u64,
}

impl MiValue {
    /// The statistic named by `o`.
    pub fn get(&self, o: Objective) -> f64 {
        match o {
            Objective::Mi => self.mi,
            Objective::Nmi => self.nmi,
        }
    }
}

/// MI and NMI of the valid part of `h`. With `parzen`, the joint histogram is first convolved with
/// the separable binomial kernel [1 2 1]/4 ⊗ [1 2 1]/4 (mass at the border is renormalised). An
/// empty histogram gives MI 0, NMI 1.
pub fn mutual_information(h: &JointHist, parzen: bool) -> MiValue {
    let (r, c, s) = (h.rows, h.cols, h.stride());
    let n = h.valid_count();
    if n == 0 {
        return MiValue {
            mi: 0.0,
            nmi: 1.0,
            n: 0,
        };
    }
    let mut p = vec![0f64; r * c];
    if parzen {
        // Separable pass 1 (along gray), pass 2 (along reflectivity); zero padding, renormalised
        // by the total below.
        let mut tmp = vec![0f64; r * c];
        for i in 0..r {
            for j in 0..c {
                let v = h.counts[i * s + j] as f64;
                if v == 0.0 {
                    continue;
                }
                tmp[i * c + j] += 2.0 * v;
                if j > 0 {
                    tmp[i * c + j - 1] += v;
                }
                if j + 1 < c {
                    tmp[i * c + j + 1] += v;
                }
            }
        }
        for i in 0..r {
            for j in 0..c {
                let v = tmp[i * c + j];
                if v == 0.0 {
                    continue;
                }
                p[i * c + j] += 2.0 * v;
                if i > 0 {
                    p[(i - 1) * c + j] += v;
                }
                if i + 1 < r {
                    p[(i + 1) * c + j] += v;
                }
            }
        }
    } else {
        for i in 0..r {
            for j in 0..c {
                p[i * c + j] = h.counts[i * s + j] as f64;
            }
        }
    }
    let total: f64 = p.iter().sum();
    let mut px = vec![0f64; r];
    let mut py = vec![0f64; c];
    let mut hxy = 0.0;
    for i in 0..r {
        for j in 0..c {
            let v = p[i * c + j];
            if v > 0.0 {
                px[i] += v;
                py[j] += v;
                hxy -= v * v.ln();
            }
        }
    }
    // H = ln(T) − Σ v ln v / T for un-normalised masses v summing to T.
    let ent = |sum_vlnv: f64| total.ln() + sum_vlnv / total;
    let hxy = ent(hxy);
    let hx = ent(-px
        .iter()
        .filter(|&&v| v > 0.0)
        .map(|&v| v * v.ln())
        .sum::<f64>());
    let hy = ent(-py
        .iter()
        .filter(|&&v| v > 0.0)
        .map(|&v| v * v.ln())
        .sum::<f64>());
    let mi = (hx + hy - hxy).max(0.0);
    let nmi = if hxy > 0.0 { (hx + hy) / hxy } else { 1.0 };
    MiValue { mi, nmi, n }
}

/// MI and NMI of one pose under a [`Pooling`]: `hists` holds one joint histogram (returned as
/// [`mutual_information`] scores it) or one per pair. Per pair, each pair's statistics are weighted
/// by its share of the points (every point counts in its pair's histogram, on a valid pixel or
/// in the invalid column), as the smooth estimator weights them; `n` is the points that counted.
pub fn pooled_information(hists: &[JointHist], parzen: bool) -> MiValue {
    if let [h] = hists {
        return mutual_information(h, parzen);
    }
    let sizes: Vec<u64> = hists
        .iter()
        .map(|h| h.valid_count() + h.invalid_count())
        .collect();
    let total = sizes.iter().sum::<u64>();
    if total == 0 {
        return MiValue {
            mi: 0.0,
            nmi: 1.0,
            n: 0,
        };
    }
    let mut out = MiValue {
        mi: 0.0,
        nmi: 0.0,
        n: 0,
    };
    for (h, &size) in hists.iter().zip(&sizes) {
        let w = size as f64 / total as f64;
        let v = mutual_information(h, parzen);
        out.mi += w * v.mi;
        out.nmi += w * v.nmi;
        out.n += v.n;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hist_from_pairs(rows: usize, cols: usize, pairs: &[(usize, usize)]) -> JointHist {
        let mut h = JointHist::new(rows, cols);
        let s = h.stride();
        for &(x, y) in pairs {
            h.counts[x * s + y] += 1;
        }
        h
    }

    #[test]
    fn independent_uniform_has_zero_mi() {
        // Every (x, y) pair equally often: p(x,y) = p(x)p(y) exactly.
        let pairs: Vec<_> = (0..4).flat_map(|x| (0..4).map(move |y| (x, y))).collect();
        let v = mutual_information(&hist_from_pairs(4, 4, &pairs), false);
        assert!(v.mi.abs() < 1e-12 && (v.nmi - 1.0).abs() < 1e-12);
    }

    #[test]
    fn deterministic_relation_gives_marginal_entropy() {
        // Y = X over 4 equiprobable values: MI = H(X) = ln 4, NMI = 2.
        let pairs: Vec<_> = (0..400).map(|i| (i % 4, i % 4)).collect();
        let mut h = hist_from_pairs(4, 5, &pairs);
        // Invalid points must not count.
        let inv = h.invalid_col();
        let s = h.stride();
        h.counts[inv] = 1000;
        h.counts[s + inv] = 7;
        let v = mutual_information(&h, false);
        assert!((v.mi - 4f64.ln()).abs() < 1e-12, "{v:?}");
        assert!((v.nmi - 2.0).abs() < 1e-12);
        assert_eq!(v.n, 400);
        assert_eq!(h.invalid_count(), 1007);
    }

    #[test]
    fn matches_a_direct_probability_computation() {
        // Independent reference: p log p/(p_x p_y) summed over cells.
        let pairs: Vec<_> = (0..997)
            .map(|i: usize| ((i * 7) % 5, (i * i + 3 * i) % 6))
            .collect();
        let h = hist_from_pairs(5, 6, &pairs);
        let n = pairs.len() as f64;
        let mut pxy = [[0f64; 6]; 5];
        for &(x, y) in &pairs {
            pxy[x][y] += 1.0 / n;
        }
        let px: Vec<f64> = (0..5).map(|x| pxy[x].iter().sum()).collect();
        let py: Vec<f64> = (0..6).map(|y| (0..5).map(|x| pxy[x][y]).sum()).collect();
        let mut mi = 0.0;
        for x in 0..5 {
            for y in 0..6 {
                if pxy[x][y] > 0.0 {
                    mi += pxy[x][y] * (pxy[x][y] / (px[x] * py[y])).ln();
                }
            }
        }
        let v = mutual_information(&h, false);
        assert!((v.mi - mi).abs() < 1e-12, "{} vs {mi}", v.mi);
        // Parzen smoothing can only lose information on this data, never create it.
        assert!(mutual_information(&h, true).mi < v.mi);
    }

    #[test]
    fn luts() {
        let zero = [0u64; 256];
        let u = bin_lut(Binning::Uniform, 32, &zero);
        assert_eq!((u[0], u[7], u[8], u[255]), (0, 0, 1, 31));
        // Data concentrated on 100..=103: equalised bins spread those four values over all bins.
        let mut c = [0u64; 256];
        c[100..=103].fill(1000);
        let e = bin_lut(Binning::Equalized, 4, &c);
        assert_eq!(&e[100..=103], &[0, 1, 2, 3]);
        assert_eq!(e[0], 0);
        assert_eq!(e[255], 3);
        let mut cfg = MiConfig::default();
        assert!(cfg.validate().is_ok());
        cfg.bins_gray = 256;
        assert!(cfg.validate().is_err());
    }

    #[test]
    fn names_round_trip_and_unknown_names_the_flag() {
        for o in [Objective::Mi, Objective::Nmi] {
            assert_eq!(o.to_string().parse::<Objective>().unwrap(), o);
        }
        for b in [Binning::Uniform, Binning::Equalized] {
            assert_eq!(b.to_string().parse::<Binning>().unwrap(), b);
        }
        // The serde names are the CLI names, so a report's echo can be passed back as a flag.
        assert_eq!(serde_json::to_value(Objective::Nmi).unwrap(), "nmi");
        assert_eq!(
            serde_json::to_value(Binning::Equalized).unwrap(),
            "equalized"
        );
        let e = "MI".parse::<Objective>().unwrap_err().to_string();
        assert!(
            e.starts_with("--objective \"MI\"") && !e.contains('\n'),
            "{e}"
        );
        let e = "quantile".parse::<Binning>().unwrap_err().to_string();
        assert!(e.starts_with("--binning"), "{e}");
    }
}
