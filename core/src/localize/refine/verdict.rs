//! The verdict on a refinement: its [`Grade`], judged from its covariance alone ([`judge`]), or
//! the typed [`Stop`] that refuses it. The grade is what the node serves by and what the
//! detection pipeline reads (`quality.grade` of the pose file): `precise` within the
//! `[quality] max-sigma-*` limits, `coarse` within `coarse-max-sigma-*`, `refused` otherwise.

use crate::localize::error::{InformationError, Refusal};
pub use crate::localize::mi::space::Axis;
use crate::localize::refine::uncertainty::Uncertainty;
use serde::ser::SerializeMap;
use serde::{Serialize, Serializer};
use std::fmt;

/// The `[quality]` limit group an axis is judged by: `xy`, `z`, `yaw` or `tilt`.
pub fn limit_group(axis: Axis) -> &'static str {
    match axis {
        Axis::X | Axis::Y => "xy",
        Axis::Z => "z",
        Axis::Yaw => "yaw",
        Axis::Pitch | Axis::Roll => "tilt",
    }
}

/// The σ limits a result is graded by (m, m, deg, deg: x and y, z, yaw, pitch and roll), from
/// `[quality]` ([`crate::localize::refine::quality::QualityConfig::limits`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limits {
    /// The precise grade's largest σ: `max-sigma-xy-m`, `-z-m`, `-yaw-deg`, `-tilt-deg`.
    pub precise: [f64; 4],
    /// The coarse grade's: `coarse-max-sigma-*`.
    pub coarse: [f64; 4],
}

/// A σ over a limit: the axis, its σ and the limit (m or deg).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Over {
    /// The axis.
    pub axis: Axis,
    /// Its reported σ.
    pub sigma: f64,
    /// The limit it exceeds.
    pub limit: f64,
}

impl fmt::Display for Over {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (s, l, u) = match self.axis.unit() {
            "m" => (100.0 * self.sigma, 100.0 * self.limit, " cm"),
            _ => (self.sigma, self.limit, "°"),
        };
        write!(
            f,
            "σ {} {s:.2}{u} over the {} limit {l:.2}{u}",
            self.axis,
            limit_group(self.axis)
        )
    }
}

/// Why a result is refused.
#[derive(Debug, Clone, PartialEq)]
pub enum Stop {
    /// One of the grid search's checks: in the smooth path its global ones (too few points,
    /// points lost, the optimum on the box's edge); with `--grid-only` and in the drift check,
    /// all of them.
    Grid(Refusal),
    /// The local stage has no covariance: a value that is not finite, an ascent still on its
    /// box's edge, axes that do not invert.
    Information(InformationError),
    /// The poses the data cannot tell from the answer reach the search box along this axis:
    /// the data bounds it nowhere inside the box (`reach`: how far the set was followed, m or
    /// deg).
    Unbounded {
        /// The axis the open direction runs along most.
        axis: Axis,
        /// How far it was followed without the data telling it apart.
        reach: f64,
    },
    /// A σ beyond its coarse limit.
    Sigma(Over),
    /// The composed covariance is not finite.
    NotFinite,
    /// Answers from different starts disagree beyond their combined 3σ (`refine --starts`).
    Disagree {
        /// The axis that disagrees most.
        axis: Axis,
        /// The difference (m or deg).
        difference: f64,
        /// It in combined σ.
        sigmas: f64,
    },
}

impl Stop {
    /// A short machine name: `grid`, `information`, `unbounded`, `sigma`, `not-finite`,
    /// `disagree`.
    pub fn kind(&self) -> &'static str {
        match self {
            Stop::Grid(_) => "grid",
            Stop::Information(_) => "information",
            Stop::Unbounded { .. } => "unbounded",
            Stop::Sigma(_) => "sigma",
            Stop::NotFinite => "not-finite",
            Stop::Disagree { .. } => "disagree",
        }
    }

    /// The axis the refusal names, if it names one.
    pub fn axis(&self) -> Option<Axis> {
        match self {
            Stop::Unbounded { axis, .. } | Stop::Disagree { axis, .. } => Some(*axis),
            Stop::Sigma(o) => Some(o.axis),
            Stop::Grid(Refusal::OnEdge { axis } | Refusal::NoBasin { axis, .. }) => {
                Axis::from_name(axis)
            }
            _ => None,
        }
    }
}

impl fmt::Display for Stop {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Stop::Grid(r) => write!(f, "{r}"),
            Stop::Information(e) => write!(f, "{e}"),
            Stop::Unbounded { axis, reach } => write!(
                f,
                "unbounded along {axis}: the data cannot tell the answer from poses {reach:.2} {} away, at the search box's edge; widen --search or add frames",
                axis.unit()
            ),
            Stop::Sigma(o) => write!(f, "{o} (coarse)"),
            Stop::NotFinite => write!(f, "uncertainty: the reported covariance is not finite"),
            Stop::Disagree {
                axis,
                difference,
                sigmas,
            } => write!(
                f,
                "answers from different starts disagree on {axis} by {difference:.3} {} ({sigmas:.1} combined σ > 3)",
                axis.unit()
            ),
        }
    }
}

/// The grade of a result.
#[derive(Debug, Clone, PartialEq)]
pub enum Grade {
    /// Every σ within the `[quality] max-sigma-*` limits.
    Precise,
    /// Every σ within the coarse limits, this one (the farthest over, relative to its limit)
    /// beyond its precise limit.
    Coarse(Over),
    /// Refused, and why.
    Refused(Stop),
}

impl Grade {
    /// `precise`, `coarse` or `refused`.
    pub fn name(&self) -> &'static str {
        match self {
            Grade::Precise => "precise",
            Grade::Coarse(_) => "coarse",
            Grade::Refused(_) => "refused",
        }
    }

    /// Its rank for choosing between results: precise 2, coarse 1, refused 0 ([`rank_of`]).
    pub fn rank(&self) -> u8 {
        rank_of(self.name())
    }

    /// Served (precise or coarse).
    pub fn served(&self) -> bool {
        !matches!(self, Grade::Refused(_))
    }

    /// The stop, when refused.
    pub fn stop(&self) -> Option<&Stop> {
        match self {
            Grade::Refused(s) => Some(s),
            _ => None,
        }
    }
}

impl fmt::Display for Grade {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Grade::Precise => f.write_str("precise"),
            Grade::Coarse(o) => write!(f, "coarse: {o} (precise)"),
            Grade::Refused(s) => write!(f, "refused: {s}"),
        }
    }
}

/// Reports and pose files carry the grade as `grade` (its name), `accepted` (served),
/// `reason` (why it is not precise, one line; `null` when precise) and, when refused,
/// `refused` (the stop's kind and the axis it names).
impl Serialize for Grade {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut m = s.serialize_map(None)?;
        m.serialize_entry("grade", self.name())?;
        m.serialize_entry("accepted", &self.served())?;
        let reason = match self {
            Grade::Precise => None,
            Grade::Coarse(o) => Some(format!("{o} (precise)")),
            Grade::Refused(st) => Some(st.to_string()),
        };
        m.serialize_entry("reason", &reason)?;
        if let Grade::Refused(st) = self {
            m.serialize_entry(
                "refused",
                &serde_json::json!({ "stop": st.kind(), "axis": st.axis() }),
            )?;
        }
        m.end()
    }
}

/// A grade's rank by its name, as pose files spell it: `precise` 2, `coarse` 1, anything else
/// (`refused`, an unknown name) 0.
pub fn rank_of(name: &str) -> u8 {
    match name {
        "precise" => 2,
        "coarse" => 1,
        _ => 0,
    }
}

/// The precise and coarse limits of an axis (m or deg).
fn limits(axis: Axis, l: &Limits) -> (f64, f64) {
    let k = match limit_group(axis) {
        "xy" => 0,
        "z" => 1,
        "yaw" => 2,
        _ => 3,
    };
    (l.precise[k], l.coarse[k])
}

/// The grade of covariance `u` under limits `q`, from its σ alone (the data's, `gate_sigma`,
/// when it has one; else the reported `sigma`): an axis the indifference set left open refuses
/// it ([`Stop::Unbounded`]), then a covariance that is not finite, then the σ farthest beyond
/// its coarse limit (relative to it); otherwise the σ farthest beyond its precise limit makes
/// it coarse, and none makes it precise.
pub fn judge(u: &Uncertainty, q: &Limits) -> Grade {
    if let Some((axis, reach)) = u.unbounded {
        return Grade::Refused(Stop::Unbounded { axis, reach });
    }
    let judged = if u.gate_sigma.len() == u.axes.len() {
        &u.gate_sigma
    } else {
        &u.sigma
    };
    if !u.is_finite() || !judged.iter().all(|s| s.is_finite()) {
        return Grade::Refused(Stop::NotFinite);
    }
    let over = |pick: fn((f64, f64)) -> f64| {
        u.axes
            .iter()
            .zip(judged)
            .filter_map(|(a, s)| {
                let axis = Axis::from_name(a)?;
                let limit = pick(limits(axis, q));
                (*s > limit).then_some(Over {
                    axis,
                    sigma: *s,
                    limit,
                })
            })
            .max_by(|a, b| (a.sigma / a.limit).total_cmp(&(b.sigma / b.limit)))
    };
    if let Some(o) = over(|l| l.1) {
        Grade::Refused(Stop::Sigma(o))
    } else if let Some(o) = over(|l| l.0) {
        Grade::Coarse(o)
    } else {
        Grade::Precise
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The default `[quality]` limits (`QualityConfig::default().limits()`, spelled out: the
    /// config's module imports this one).
    const DEFAULT: Limits = Limits {
        precise: [0.05, 0.05, 0.15, 0.5],
        coarse: [0.5, 0.5, 1.0, 2.0],
    };

    fn cov(sigma: [f64; 4]) -> Uncertainty {
        Uncertainty {
            axes: ["x", "y", "z", "yaw"].map(String::from).to_vec(),
            units: ["m", "m", "m", "deg"].map(String::from).to_vec(),
            sigma: sigma.to_vec(),
            matrix: (0..4)
                .map(|i| {
                    (0..4)
                        .map(|j| if i == j { sigma[i] * sigma[i] } else { 0.0 })
                        .collect()
                })
                .collect(),
            ..Uncertainty::default()
        }
    }

    /// Precise within the precise limits, coarse within the coarse ones (naming the axis
    /// farthest over relative to its limit), refused beyond them, naming that axis.
    #[test]
    fn the_grade_follows_the_sigma_against_both_limits() {
        let q = DEFAULT;
        assert_eq!(judge(&cov([0.01, 0.02, 0.03, 0.1]), &q), Grade::Precise);
        // Exactly at the limit is within it.
        assert_eq!(judge(&cov([0.05, 0.05, 0.05, 0.15]), &q), Grade::Precise);
        // x 3× over its 5 cm, yaw 4× over its 0.15°: yaw is named.
        let g = judge(&cov([0.15, 0.02, 0.03, 0.6]), &q);
        let Grade::Coarse(o) = g else { panic!("{g:?}") };
        assert_eq!((o.axis, o.sigma, o.limit), (Axis::Yaw, 0.6, 0.15));
        assert!(g.served());
        // Beyond the coarse 0.5 m on z.
        let g = judge(&cov([0.15, 0.02, 0.6, 0.2]), &q);
        assert_eq!(
            g,
            Grade::Refused(Stop::Sigma(Over {
                axis: Axis::Z,
                sigma: 0.6,
                limit: 0.5
            }))
        );
        assert!(!g.served());
        assert!(g
            .to_string()
            .contains("σ z 60.00 cm over the z limit 50.00 cm"));
    }

    /// An open direction refuses whatever the σ, naming its axis; a covariance that is not
    /// finite refuses too.
    #[test]
    fn an_unbounded_axis_or_a_non_finite_sigma_refuses() {
        let q = DEFAULT;
        let mut u = cov([0.01, 0.01, 0.01, 0.01]);
        u.unbounded = Some((Axis::Y, 1.0));
        let g = judge(&u, &q);
        assert_eq!(g.stop().and_then(Stop::axis), Some(Axis::Y));
        assert_eq!(g.stop().map(Stop::kind), Some("unbounded"));
        let mut u = cov([0.01, f64::NAN, 0.01, 0.01]);
        assert_eq!(judge(&u, &q), Grade::Refused(Stop::NotFinite));
        u.sigma[1] = 0.01;
        u.matrix[0][3] = f64::INFINITY;
        assert_eq!(judge(&u, &q), Grade::Refused(Stop::NotFinite));
    }

    /// The data's σ (`gate_sigma`) is judged where the covariance has it: the reported σ, widened
    /// for the clusters' few degrees of freedom and with the intrinsics' part, may lie beyond.
    #[test]
    fn the_data_s_sigma_is_judged_when_given() {
        let q = DEFAULT;
        let mut u = cov([0.06, 0.01, 0.01, 0.1]);
        assert!(matches!(judge(&u, &q), Grade::Coarse(_)));
        u.gate_sigma = vec![0.045, 0.01, 0.01, 0.1];
        assert_eq!(judge(&u, &q), Grade::Precise);
        u.gate_sigma[3] = f64::NAN;
        assert_eq!(judge(&u, &q), Grade::Refused(Stop::NotFinite));
    }

    /// The tilt axes are judged by the tilt limits; the configured limits are the ones used.
    #[test]
    fn the_tilt_and_configured_limits_apply() {
        let mut u = cov([0.01, 0.01, 0.01, 0.01]);
        u.axes.extend(["pitch".into(), "roll".into()]);
        u.sigma.extend([1.0, 0.1]);
        let q = DEFAULT;
        let Grade::Coarse(o) = judge(&u, &q) else {
            panic!()
        };
        assert_eq!(o.axis, Axis::Pitch);
        let strict = Limits {
            coarse: [0.5, 0.5, 1.0, 0.8],
            ..DEFAULT
        };
        assert_eq!(judge(&u, &strict).stop().map(Stop::kind), Some("sigma"));
    }

    /// The serialized grade: its name, served or not, the reason and the typed refusal.
    #[test]
    fn the_grade_serializes_its_name_and_typed_refusal() {
        let v = serde_json::to_value(Grade::Refused(Stop::Unbounded {
            axis: Axis::X,
            reach: 1.0,
        }))
        .unwrap();
        assert_eq!(v["grade"], "refused");
        assert_eq!(v["accepted"], false);
        assert_eq!(v["refused"]["stop"], "unbounded");
        assert_eq!(v["refused"]["axis"], "x");
        let v = serde_json::to_value(Grade::Precise).unwrap();
        assert_eq!(
            v,
            serde_json::json!({"grade": "precise", "accepted": true, "reason": null})
        );
    }
}
