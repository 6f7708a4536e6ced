//! The preprocessing registry: the one place that knows which
//! "input frame → display frame" ([`Preprocess`]) each display system runs.
//! `nedrt sim`, `nedrt eval`, the studies and `nedrt run --preprocess` all
//! build theirs here, so a method is never special-cased in a command. A
//! new preprocessor is one file in the layer that owns its physics or
//! engine, plus one arm in [`for_method`].

use std::collections::HashMap;
use std::sync::Arc;

use nedrt_core::Preprocess;
use nedrt_core::calib::Calibration;
use nedrt_optics::sim::{
    Method, Objective, Prepared, SolveMode, SolvedPrefilter, objective_depths_d,
};

use crate::EngineError;
use crate::network::Network;
/// The D-CNN's parts, where they were before the unrolled model joined them.
pub use crate::network::{
    Chain, DcnnInput, RawWiener, card_path, dcnn_input, dcnn_lines, dcnn_system, stage_note,
    wiener_stages,
};

/// The preprocessing of `method`: none (conventional, DOE only), its
/// Wiener prefilter from `prepared` (AI, DOE + Wiener), or its network (a
/// D-CNN or an unrolled model), taken from `dcnns` (nedrt-command's
/// `DcnnOptions::load_for` loads them).
pub fn for_method(
    method: Method,
    prepared: &Prepared,
    dcnns: &mut HashMap<Method, Network>,
) -> Result<Box<dyn Preprocess>, EngineError> {
    if method.uses_dcnn() {
        return match dcnns.remove(&method) {
            Some(n) => n.into_preprocess(method, prepared),
            None => Err(EngineError::Unavailable(format!(
                "no D-CNN loaded for {method}"
            ))),
        };
    }
    Ok(prepared.preprocessor(method)?)
}

/// How the display image is made from a frame, given a method's optics
/// (`--prefilter`): the method's own preprocessing, or one of the
/// least-squares family of nedrt-optics' `optimal` module, which solve for
/// the display image against `objective` over the headline depths.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Prefilter {
    /// The method's own: none, its Wiener prefilter, or its D-CNN.
    Native,
    /// The linear least-squares prefilter, clamped.
    Lsq(Objective),
    /// `lsq` and this many projected-gradient steps.
    Refine(usize, Objective),
    /// `lsq` and this many steps of the split solver (ADMM: the panel's
    /// box split off, the quadratic solved exactly each step).
    Admm(usize, Objective),
    /// The bounded least-squares optimum (to 0.001 dB).
    Optimal(Objective),
}

/// Most refinement steps `refine:K` takes (past it, use `optimal`).
pub const MAX_REFINE_STEPS: usize = 1000;

impl Prefilter {
    /// The objective of the least-squares family when none is named: the
    /// multifocal target, the quantity training optimises
    /// (evaluation protocol).
    pub const DEFAULT_OBJECTIVE: Objective = Objective::Target;

    pub fn is_native(self) -> bool {
        self == Prefilter::Native
    }

    /// The depths its PSFs must be prepared at (none for `native`).
    pub fn depths_d(self, calib: &Calibration) -> Vec<f64> {
        if self.is_native() {
            Vec::new()
        } else {
            objective_depths_d(calib)
        }
    }

    /// The depths every one of `prefilters` needs, deduplicated.
    pub fn all_depths_d(prefilters: &[Prefilter], calib: &Calibration) -> Vec<f64> {
        if prefilters.iter().all(|p| p.is_native()) {
            Vec::new()
        } else {
            objective_depths_d(calib)
        }
    }

    /// What it solves against (`None` for `native`).
    pub fn objective(self) -> Option<Objective> {
        match self {
            Prefilter::Native => None,
            Prefilter::Lsq(o)
            | Prefilter::Refine(_, o)
            | Prefilter::Admm(_, o)
            | Prefilter::Optimal(o) => Some(o),
        }
    }

    /// The same prefilter against `objective` (`native` stays itself).
    pub fn with_objective(self, objective: Objective) -> Self {
        match self {
            Prefilter::Native => Prefilter::Native,
            Prefilter::Lsq(_) => Prefilter::Lsq(objective),
            Prefilter::Refine(k, _) => Prefilter::Refine(k, objective),
            Prefilter::Admm(k, _) => Prefilter::Admm(k, objective),
            Prefilter::Optimal(_) => Prefilter::Optimal(objective),
        }
    }

    /// The row name of `method` with this prefilter ("ai", "ai optimal@target").
    pub fn label(self, method_name: &str) -> String {
        match self {
            Prefilter::Native => method_name.to_string(),
            other => format!("{method_name} {other}"),
        }
    }
}

impl std::fmt::Display for Prefilter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Prefilter::Native => f.write_str("native"),
            Prefilter::Lsq(o) => write!(f, "lsq@{}", o.name()),
            Prefilter::Refine(k, o) => write!(f, "refine:{k}@{}", o.name()),
            Prefilter::Admm(k, o) => write!(f, "admm:{k}@{}", o.name()),
            Prefilter::Optimal(o) => write!(f, "optimal@{}", o.name()),
        }
    }
}

impl std::str::FromStr for Prefilter {
    type Err = String;
    /// `native`, `lsq`, `refine:K`, `admm:K` or `optimal`, all but the
    /// first with an optional `@sharp` or `@target`.
    fn from_str(s: &str) -> Result<Self, String> {
        const CHOICES: &str = "choose native, lsq, refine:K, admm:K or optimal (K ≥ 1 steps), \
             all but native optionally with @sharp or @target";
        let (kind, objective) = match s.split_once('@') {
            Some((k, o)) => (
                k,
                o.parse::<Objective>()
                    .map_err(|e| format!("prefilter {s:?}: {e}"))?,
            ),
            None => (s, Self::DEFAULT_OBJECTIVE),
        };
        match kind {
            "native" if !s.contains('@') => Ok(Prefilter::Native),
            "lsq" => Ok(Prefilter::Lsq(objective)),
            "optimal" => Ok(Prefilter::Optimal(objective)),
            _ => {
                let (make, k): (fn(usize, Objective) -> Prefilter, _) =
                    match (kind.strip_prefix("refine:"), kind.strip_prefix("admm:")) {
                        (Some(k), _) => (Prefilter::Refine, k),
                        (_, Some(k)) => (Prefilter::Admm, k),
                        _ => return Err(format!("unknown prefilter {s:?}; {CHOICES}")),
                    };
                match k.parse::<usize>() {
                    Ok(k) if (1..=MAX_REFINE_STEPS).contains(&k) => Ok(make(k, objective)),
                    _ => Err(format!(
                        "prefilter {s:?}: the number of steps must be a whole number from 1 to \
                         {MAX_REFINE_STEPS}"
                    )),
                }
            }
        }
    }
}

/// The preprocessing of `method` with `prefilter`: [`for_method`] for
/// `native`, else the method's optics' least-squares problem solved as asked.
pub fn for_system(
    method: Method,
    prefilter: Prefilter,
    prepared: &Prepared,
    dcnns: &mut HashMap<Method, Network>,
) -> Result<Box<dyn Preprocess>, EngineError> {
    if prefilter.is_native() {
        return for_method(method, prepared, dcnns);
    }
    solved(method, prefilter, prepared, false)
}

/// A least-squares `prefilter` (not `native`) on `method`'s optics;
/// `warm`: `refine:K` and `admm:K` go on over still frames
/// ([`SolvedPrefilter::warm_started`], the frame budget's levels).
pub fn solved(
    method: Method,
    prefilter: Prefilter,
    prepared: &Prepared,
    warm: bool,
) -> Result<Box<dyn Preprocess>, EngineError> {
    let (mode, objective) = match prefilter {
        Prefilter::Native => {
            return Err(EngineError::Unavailable(format!(
                "{method}'s own preprocessing is not a least-squares solve"
            )));
        }
        Prefilter::Lsq(o) => (SolveMode::Linear, o),
        Prefilter::Refine(k, o) => (SolveMode::Refine(k), o),
        Prefilter::Admm(k, o) => (SolveMode::Admm(k), o),
        Prefilter::Optimal(o) => (SolveMode::Optimal, o),
    };
    let problem = prepared.display_problem(method, objective)?;
    if matches!(mode, SolveMode::Admm(_)) && !problem.has_split() {
        return Err(EngineError::Unavailable(format!(
            "{prefilter} of {method}: its PSFs are not mirror-symmetric, so the split solver has \
             no exact data step; use refine:K"
        )));
    }
    let solver = SolvedPrefilter::new(method.name(), Arc::new(problem), mode);
    Ok(Box::new(if warm { solver.warm_started() } else { solver }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn prefilter_names_round_trip_and_bad_ones_explain() {
        for p in [
            Prefilter::Native,
            Prefilter::Lsq(Objective::Sharp),
            Prefilter::Refine(3, Objective::Target),
            Prefilter::Admm(5, Objective::Sharp),
            Prefilter::Optimal(Objective::Sharp),
        ] {
            assert_eq!(p.to_string().parse::<Prefilter>(), Ok(p));
        }
        assert_eq!(
            "optimal".parse::<Prefilter>(),
            Ok(Prefilter::Optimal(Objective::Target))
        );
        assert_eq!(
            "refine:10".parse::<Prefilter>(),
            Ok(Prefilter::Refine(10, Objective::Target))
        );
        assert_eq!(
            "admm:3".parse::<Prefilter>(),
            Ok(Prefilter::Admm(3, Objective::Target))
        );
        for (bad, says) in [
            ("wiener", "choose native"),
            ("refine:0", "from 1 to"),
            ("refine:", "from 1 to"),
            ("refine:x", "whole number"),
            ("refine:1001", "1000"),
            ("admm:0", "from 1 to"),
            ("admm:two", "whole number"),
            ("optimal@blurry", "sharp or target"),
            ("native@sharp", "choose native"),
        ] {
            let e = bad.parse::<Prefilter>().unwrap_err();
            assert!(e.contains(says) && e.contains(bad), "{bad}: {e}");
        }
        assert_eq!(Prefilter::Native.label("ai"), "ai");
        assert_eq!(
            Prefilter::Lsq(Objective::Sharp).label("doe+wiener"),
            "doe+wiener lsq@sharp"
        );
    }
}
