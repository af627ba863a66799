//! The MI estimator's flags (`--bins`, `--objective`, `--binning`, `--no-parzen`), shared by
//! `refine` and `study` so both parse and validate them the same way (docs/refine.md
//! "Estimator").

use crate::error::{Error, Result};
use crate::localize::mi::{Binning, MiConfig, Objective, MAX_GRAY_BINS, MAX_REFLECTIVITY_BINS};

/// Estimator flags; their defaults are [`MiConfig::default`]'s, so leaving them out changes
/// nothing.
#[derive(Debug, Clone, clap::Args)]
pub struct EstimatorArgs {
    /// Histogram bins of both variables, reflectivity and gray (2..=255). The default keeps the
    /// joint histogram small enough for its small-sample bias to stay below the alignment signal.
    #[arg(long, value_name = "N", default_value_t = MiConfig::default().bins_gray.to_string())]
    pub bins: String,
    /// Statistic the search maximises: `mi` (mutual information, nats) or `nmi` (normalised MI,
    /// (H(X)+H(Y))/H(X,Y)).
    #[arg(long, value_name = "mi|nmi", default_value_t = MiConfig::default().objective.to_string())]
    pub objective: String,
    /// Bin edges: `equalized` (quantiles of the data's own histogram) or `uniform` (equal width
    /// over 0–255).
    #[arg(long, value_name = "equalized|uniform", default_value_t = MiConfig::default().binning.to_string())]
    pub binning: String,
    /// Turn off the 3×3 binomial Parzen smoothing of the joint histogram (on by default).
    #[arg(long)]
    pub no_parzen: bool,
}

impl EstimatorArgs {
    /// The estimator these flags select; a bad value is a one-line error naming its flag.
    pub(crate) fn config(&self) -> Result<MiConfig> {
        // Strings rather than clap's typed values: clap's own errors are several lines with exit
        // code 2, the refine CLI's convention is one line naming the flag (as --mode, --search).
        let bins: usize = self
            .bins
            .trim()
            .parse()
            .ok()
            .filter(|b| (2..=MAX_GRAY_BINS.min(MAX_REFLECTIVITY_BINS)).contains(b))
            .ok_or_else(|| {
                Error::arg_quoted(
                    "--bins",
                    &self.bins,
                    format!(
                        "expected a whole number in 2..={}",
                        MAX_GRAY_BINS.min(MAX_REFLECTIVITY_BINS)
                    ),
                )
            })?;
        let cfg = MiConfig {
            bins_reflectivity: bins,
            bins_gray: bins,
            binning: self.binning.parse::<Binning>()?,
            objective: self.objective.parse::<Objective>()?,
            parzen: !self.no_parzen,
            ..MiConfig::default()
        };
        cfg.validate()?;
        Ok(cfg)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Debug, Parser)]
    struct Cli {
        #[command(flatten)]
        est: EstimatorArgs,
    }

    fn parse(args: &[&str]) -> Result<MiConfig> {
        let cli = Cli::try_parse_from(std::iter::once("t").chain(args.iter().copied()))
            .map_err(|e| Error::Usage(e.to_string()))?;
        cli.est.config()
    }

    #[test]
    fn no_flags_give_the_default_estimator() {
        assert_eq!(parse(&[]).unwrap(), MiConfig::default());
    }

    #[test]
    fn flags_set_each_field() {
        let c = parse(&[
            "--bins",
            "16",
            "--objective",
            "nmi",
            "--binning",
            "uniform",
            "--no-parzen",
        ])
        .unwrap();
        assert_eq!(
            c,
            MiConfig {
                bins_reflectivity: 16,
                bins_gray: 16,
                binning: Binning::Uniform,
                objective: Objective::Nmi,
                parzen: false,
                ..MiConfig::default()
            }
        );
    }

    #[test]
    fn bad_values_name_their_flag() {
        for (args, flag) in [
            (&["--bins", "1"][..], "--bins"),
            (&["--bins", "256"], "--bins"),
            (&["--bins", "32.5"], "--bins"),
            (&["--bins=-4"], "--bins"),
            (&["--objective", "entropy"], "--objective"),
            (&["--binning", "log"], "--binning"),
        ] {
            let e = parse(args).unwrap_err().to_string();
            assert!(e.starts_with(flag) && !e.contains('\n'), "{args:?}: {e}");
        }
        assert_eq!(parse(&["--bins", "255"]).unwrap().bins_gray, 255);
        assert_eq!(parse(&["--bins", "2"]).unwrap().bins_reflectivity, 2);
    }
}
