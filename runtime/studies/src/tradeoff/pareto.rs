//! The Pareto front of (latency, quality) points and the configuration
//! picker: pure functions of a table, so they are tested on their own.

use serde::{Deserialize, Serialize};

/// One measured configuration: what it costs and what it gives.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Point {
    /// The configuration, as `nedrt` names it (method, model, backend, precision).
    pub name: String,
    /// Latency per frame, milliseconds; `None` where it was not measured
    /// (over the time limit), which keeps the point off the front and out
    /// of the picker.
    pub latency_ms: Option<f64>,
    /// Mean PSNR over 0–2.5 D against the sharp image, dB.
    pub mean_psnr_db: f64,
    /// Worst depth's PSNR over 0–2.5 D, dB.
    pub worst_psnr_db: f64,
    pub mean_ssim: f64,
}

/// Whether `a` dominates `b`: no slower, no worse, and better in one.
fn dominates(a: &Point, b: &Point) -> bool {
    match (a.latency_ms, b.latency_ms) {
        (Some(la), Some(lb)) => {
            la <= lb
                && a.mean_psnr_db >= b.mean_psnr_db
                && (la < lb || a.mean_psnr_db > b.mean_psnr_db)
        }
        _ => false,
    }
}

/// For each point, whether it lies on the Pareto front (fastest for its
/// quality: no other measured point is both at least as fast and at least
/// as good, and better in one). Unmeasured points are never on it.
pub fn pareto_front(points: &[Point]) -> Vec<bool> {
    points
        .iter()
        .map(|p| p.latency_ms.is_some() && !points.iter().any(|q| dominates(q, p)))
        .collect()
}

/// What the user asks of a configuration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Requirement {
    /// Quality floor: mean PSNR over 0–2.5 D, dB.
    pub min_mean_psnr_db: f64,
    /// Optional floor on the worst depth, dB.
    pub min_worst_psnr_db: Option<f64>,
    /// Latency budget per frame, milliseconds.
    pub max_latency_ms: f64,
}

impl Requirement {
    fn quality_met(&self, p: &Point) -> bool {
        p.mean_psnr_db >= self.min_mean_psnr_db
            && self.min_worst_psnr_db.is_none_or(|w| p.worst_psnr_db >= w)
    }
}

/// The picker's answer.
#[derive(Debug, Clone, PartialEq)]
pub enum Pick<'a> {
    /// The fastest configuration meeting both (ties: the better quality).
    Chosen(&'a Point),
    /// Some configurations reach the quality floor, but none within the
    /// budget; the fastest of them is named.
    OverBudget { fastest_good_enough: &'a Point },
    /// No measured configuration reaches the quality floor; the best one is named.
    QualityUnreachable { best: &'a Point },
    /// The table holds no measured configuration.
    Empty,
}

/// Picks the fastest measured configuration that meets `req`.
pub fn pick<'a>(points: &'a [Point], req: &Requirement) -> Pick<'a> {
    let measured: Vec<&Point> = points.iter().filter(|p| p.latency_ms.is_some()).collect();
    if measured.is_empty() {
        return Pick::Empty;
    }
    let faster = |a: &&Point, b: &&Point| {
        a.latency_ms
            .unwrap_or(f64::INFINITY)
            .total_cmp(&b.latency_ms.unwrap_or(f64::INFINITY))
            .then(b.mean_psnr_db.total_cmp(&a.mean_psnr_db))
    };
    let mut good: Vec<&Point> = measured
        .iter()
        .copied()
        .filter(|p| req.quality_met(p))
        .collect();
    good.sort_by(faster);
    match good.first() {
        None => Pick::QualityUnreachable {
            best: measured
                .iter()
                .copied()
                .max_by(|a, b| a.mean_psnr_db.total_cmp(&b.mean_psnr_db))
                .unwrap_or(measured[0]),
        },
        Some(&p) if p.latency_ms.unwrap_or(f64::INFINITY) <= req.max_latency_ms => Pick::Chosen(p),
        Some(&p) => Pick::OverBudget {
            fastest_good_enough: p,
        },
    }
}

impl std::fmt::Display for Pick<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let ms = |p: &Point| p.latency_ms.unwrap_or(f64::NAN);
        match self {
            Pick::Chosen(p) => write!(
                f,
                "{}: {:.2} ms per frame, mean PSNR {:.2} dB (worst depth {:.2} dB)",
                p.name,
                ms(p),
                p.mean_psnr_db,
                p.worst_psnr_db
            ),
            Pick::OverBudget {
                fastest_good_enough: p,
            } => write!(
                f,
                "no configuration meets both: the fastest one that reaches the quality floor is {} at {:.2} ms per frame (mean {:.2} dB), over the budget",
                p.name,
                ms(p),
                p.mean_psnr_db
            ),
            Pick::QualityUnreachable { best } => write!(
                f,
                "no configuration reaches the quality floor: the best is {} with mean {:.2} dB (worst depth {:.2} dB)",
                best.name, best.mean_psnr_db, best.worst_psnr_db
            ),
            Pick::Empty => write!(f, "the table holds no measured configuration"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn p(name: &str, ms: f64, mean: f64) -> Point {
        Point {
            name: name.into(),
            latency_ms: Some(ms),
            mean_psnr_db: mean,
            worst_psnr_db: mean - 2.0,
            mean_ssim: 0.7,
        }
    }

    fn table() -> Vec<Point> {
        vec![
            p("conventional", 0.1, 21.1),
            p("ai", 40.0, 22.0),
            p("doe+wiener", 45.0, 20.8),
            p("proposed-half-ort", 900.0, 22.5),
            p("proposed-half-cpu", 5000.0, 22.5),
        ]
    }

    #[test]
    fn the_front_holds_the_undominated_points() {
        let front = pareto_front(&table());
        assert_eq!(front, vec![true, true, false, true, false]);
    }

    #[test]
    fn unmeasured_points_are_neither_on_the_front_nor_picked() {
        let mut t = table();
        t.push(Point {
            latency_ms: None,
            ..p("proposed-gpu", 0.0, 30.0)
        });
        assert!(!pareto_front(&t)[5]);
        let req = Requirement {
            min_mean_psnr_db: 25.0,
            min_worst_psnr_db: None,
            max_latency_ms: 1e9,
        };
        assert!(matches!(pick(&t, &req), Pick::QualityUnreachable { .. }));
    }

    #[test]
    fn a_floor_no_configuration_reaches_is_reported_with_the_best() {
        let t = table();
        let req = Requirement {
            min_mean_psnr_db: 30.0,
            min_worst_psnr_db: None,
            max_latency_ms: 1e9,
        };
        match pick(&t, &req) {
            Pick::QualityUnreachable { best } => assert_eq!(best.mean_psnr_db, 22.5),
            other => panic!("{other:?}"),
        }
        assert!(
            pick(&t, &req)
                .to_string()
                .contains("no configuration reaches")
        );
    }

    #[test]
    fn an_easy_floor_picks_the_fastest_that_meets_it() {
        let t = table();
        let easy = Requirement {
            min_mean_psnr_db: 15.0,
            min_worst_psnr_db: None,
            max_latency_ms: 1000.0,
        };
        assert_eq!(pick(&t, &easy), Pick::Chosen(&t[0]));
        let harder = Requirement {
            min_mean_psnr_db: 22.2,
            ..easy
        };
        assert_eq!(pick(&t, &harder), Pick::Chosen(&t[3]));
        let worst_floor = Requirement {
            min_worst_psnr_db: Some(19.5),
            ..easy
        };
        assert_eq!(pick(&t, &worst_floor), Pick::Chosen(&t[1]));
    }

    #[test]
    fn a_tight_budget_names_the_fastest_good_enough() {
        let t = table();
        let req = Requirement {
            min_mean_psnr_db: 22.2,
            min_worst_psnr_db: None,
            max_latency_ms: 11.1,
        };
        assert_eq!(
            pick(&t, &req),
            Pick::OverBudget {
                fastest_good_enough: &t[3]
            }
        );
        assert_eq!(pick(&[], &req), Pick::Empty);
    }

    proptest! {
        #[test]
        fn the_pick_is_on_the_front_and_no_faster_point_qualifies(
            raw in proptest::collection::vec((0.0f64..100.0, 10.0f64..30.0), 1..20),
            floor in 10.0f64..30.0,
            budget in 0.0f64..100.0,
        ) {
            let t: Vec<Point> = raw.iter().enumerate().map(|(i, (ms, db))| p(&i.to_string(), *ms, *db)).collect();
            let front = pareto_front(&t);
            prop_assert!(front.iter().any(|f| *f));
            let req = Requirement { min_mean_psnr_db: floor, min_worst_psnr_db: None, max_latency_ms: budget };
            if let Pick::Chosen(c) = pick(&t, &req) {
                let i = t.iter().position(|q| std::ptr::eq(q, c)).expect("from the table");
                prop_assert!(front[i]);
                prop_assert!(c.mean_psnr_db >= floor && c.latency_ms.expect("measured") <= budget);
                for q in &t {
                    if q.mean_psnr_db >= floor {
                        prop_assert!(q.latency_ms >= c.latency_ms);
                    }
                }
            }
        }
    }
}
