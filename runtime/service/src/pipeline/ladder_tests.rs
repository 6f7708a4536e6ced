//! The frame budget's controller, alone and on the pacing's fake clock
//! (the source, the stage, the present slot and the present loop as one
//! event loop, [`crate::pipeline::pacing::fake_loop`]).

use super::*;
use crate::pipeline::pacing::fake_loop::{Outcome, StageCall, run_staged};
use crate::pipeline::stats::Stats;

const MS: u64 = 1_000_000;

fn level(name: &str, reference_ns: u64, quality_db: Option<f64>) -> Level {
    Level {
        name: name.into(),
        quality_db,
        reference_ns,
    }
}

/// none < Wiener < refine < a network whose start-up time is 5 ms.
fn ladder() -> Vec<Level> {
    vec![
        level("none", 3 * MS / 10, Some(20.5)),
        level("wiener", 3 * MS / 2, Some(21.6)),
        level("refine:3", 3 * MS, Some(21.8)),
        level("model", 5 * MS, Some(22.0)),
    ]
}

/// What a run on the fake clock showed, and the levels the frames ran.
struct Run {
    out: Outcome,
    /// (start, level) of each frame the stage ran.
    levels: Vec<(u64, usize)>,
    counts: Vec<LevelCounts>,
}

impl Run {
    /// Frames submitted at or after `from_ns` and before `to_ns` that were
    /// never shown (replaced before the stage or in the present slot).
    fn lost(&self, from_ns: u64, to_ns: u64) -> usize {
        self.out
            .replaced
            .iter()
            .chain(&self.out.dropped)
            .filter(|f| (from_ns..to_ns).contains(&f.submit_ns))
            .count()
    }

    /// Those shown after the refresh predicted for them.
    fn late(&self, from_ns: u64, to_ns: u64) -> usize {
        self.out
            .shown
            .iter()
            .filter(|(f, shown)| (from_ns..to_ns).contains(&f.submit_ns) && *shown > f.predicted_ns)
            .count()
    }

    /// Refreshes in `[from_ns, to_ns)` that showed no new frame.
    fn repeats(&self, from_ns: u64, to_ns: u64) -> usize {
        let period = 11_111_111;
        self.out
            .shown
            .windows(2)
            .filter(|w| (from_ns..to_ns).contains(&w[1].1))
            .map(|w| ((w[1].1 - w[0].1) / period).saturating_sub(1) as usize)
            .sum()
    }

    /// The first frame at or after `from_ns` that ran `level`.
    fn first_at(&self, level: usize, from_ns: u64) -> Option<u64> {
        self.levels
            .iter()
            .find(|&&(t, l)| t >= from_ns && l == level)
            .map(|&(t, _)| t)
    }

    /// Switches of level among the frames started in `[from_ns, to_ns)`.
    fn switches(&self, from_ns: u64, to_ns: u64) -> usize {
        let inside: Vec<usize> = self
            .levels
            .iter()
            .filter(|(t, _)| (from_ns..to_ns).contains(t))
            .map(|&(_, l)| l)
            .collect();
        inside.windows(2).filter(|w| w[0] != w[1]).count()
    }
}

/// 90 Hz for `refreshes`, a 0.7 ms present; the frame's level chosen by
/// the controller over `levels` (or `fixed`), its cost `cost(level,
/// start_ns)`, the budget from the pacing's lead as the service takes it.
fn run_ladder(
    refreshes: u64,
    levels: Vec<Level>,
    fixed: Option<usize>,
    cost: impl Fn(usize, u64) -> u64,
) -> Run {
    let stats = Stats::default();
    let mut controller = Controller::new(levels, 11 * MS);
    let mut ran = Vec::new();
    let out = run_staged(
        refreshes,
        |c: StageCall| {
            controller.set_budget_ns(frame_budget_ns(c.period_ns, c.latch_ns));
            let level = fixed.unwrap_or(controller.level());
            let ns = cost(level, c.start_ns);
            controller.observe(ns);
            ran.push((c.start_ns, level));
            ns
        },
        |_| 7 * MS / 10,
        &stats,
    );
    Run {
        out,
        levels: ran,
        counts: controller.counts().to_vec(),
    }
}

const S: u64 = 1_000_000_000;

/// The acceptance test of issue 54: the stage's time jumps from 5 to 15
/// ms on an 11.1 ms refresh (every level three times slower: another
/// application on the GPU) from 2 s to 4 s, then falls back.
#[test]
fn a_load_jump_costs_one_frame_steps_down_and_climbs_back_within_a_second() {
    let refs: Vec<u64> = ladder().iter().map(|l| l.reference_ns).collect();
    let load = |t: u64| if (2 * S..4 * S).contains(&t) { 3 } else { 1 };
    let cost = |level: usize, t: u64| refs[level] * load(t);
    let top = refs.len() - 1;

    // A fixed level: the network drops over a fifth of the frames under
    // the load.
    let fixed = run_ladder(6 * 90, ladder(), Some(top), cost);
    let fixed_lost = fixed.lost(2 * S, 4 * S);
    assert!(
        fixed_lost > 36,
        "the fixed network lost {fixed_lost} frames"
    );

    let auto = run_ladder(6 * 90, ladder(), None, cost);
    // Settled at the top before the jump, nothing lost.
    assert_eq!(auto.levels[30].1, top, "{:?}", &auto.levels[..40]);
    assert_eq!(auto.lost(S / 2, 2 * S) + auto.late(S / 2, 2 * S), 0);
    // At most one frame lost at the jump (the one queued behind the first
    // slow frame, which is shown a refresh late), none after it during the
    // load. Two refreshes show no new frame: the slow frame's, and one
    // where the pacing's estimate, which learnt the slow frame, planned
    // the source's next frame a refresh further out (pacing::jit).
    let window = (2 * S - S / 10, 4 * S);
    let (lost, late) = (auto.lost(window.0, window.1), auto.late(window.0, window.1));
    assert!(lost <= 1, "{lost} frames lost at and after the jump");
    assert!(late <= 1, "{late} frames late at and after the jump");
    let repeats = auto.repeats(window.0, window.1);
    assert!(repeats <= 2, "{repeats} refreshes without a new frame");
    let after_jump: Vec<usize> = auto
        .levels
        .iter()
        .filter(|(t, _)| *t > 2 * S + S / 20 && *t < 4 * S)
        .map(|&(_, l)| l)
        .collect();
    assert!(
        after_jump.iter().all(|&l| l < top),
        "the network ran under the load: {after_jump:?}"
    );
    // Under the load it stays at the best level that fits (the Wiener,
    // 4.5 ms; refine:3 at 9 ms is past 85 % of the budget), not lower.
    assert!(after_jump.iter().skip(5).all(|&l| l == 1), "{after_jump:?}");
    // Back at the top within a second after the load lifts, losing nothing.
    let back = auto.first_at(top, 4 * S).expect("climbs back");
    assert!(
        back < 5 * S,
        "back at the top {} ms after",
        (back - 4 * S) / MS
    );
    assert_eq!(
        auto.lost(4 * S, 6 * S - S / 10) + auto.late(4 * S, 6 * S - S / 10),
        0
    );
    assert!(auto.counts[top].left_late >= 1, "{:?}", auto.counts);
}

/// A steady load that puts a level at the budget's edge (its frames
/// jitter from 0.9 to 1.05 of the budget): the controller leaves it and
/// stays below, rather than switching back and forth.
#[test]
fn a_steady_load_at_a_levels_boundary_does_not_oscillate() {
    let refs: Vec<u64> = ladder().iter().map(|l| l.reference_ns).collect();
    let budget = frame_budget_ns(11_111_111, 1_700_000);
    // Every level scaled so the network sits at the budget.
    let scale = budget as f64 / refs[3] as f64;
    let jitter = |t: u64| 0.9 + 0.15 * ((t / 7_000_000) % 11) as f64 / 10.0;
    let scaled = |level: usize, t: u64| (refs[level] as f64 * scale * jitter(t)) as u64;
    let auto = run_ladder(6 * 90, ladder(), None, scaled);
    let switches = auto.switches(S, 6 * S);
    assert!(switches <= 2, "{switches} switches: {:?}", auto.counts);
    let lost = auto.lost(S, 6 * S) + auto.late(S, 6 * S);
    assert!(lost <= 2, "{lost} lost or late");

    // Only the network slowed (its start-up time no longer says what it
    // costs): it is tried again only after calm periods, each try costing
    // at most a frame.
    let top_only = |level: usize, t: u64| {
        if level == 3 {
            (budget as f64 * jitter(t)) as u64
        } else {
            refs[level]
        }
    };
    let auto = run_ladder(6 * 90, ladder(), None, top_only);
    let switches = auto.switches(S, 6 * S);
    assert!(switches <= 4, "{switches} switches: {:?}", auto.counts);
    let at_top = auto.counts[3].frames;
    assert!(at_top < 20, "{at_top} frames at the slowed network");
}

#[test]
fn the_controller_starts_at_the_best_level_that_fits() {
    let c = Controller::new(ladder(), 4 * MS);
    // 85 % of 4 ms: refine:3's 3 ms fits, the network's 5 does not.
    assert_eq!(c.level(), 2);
    let c = Controller::new(ladder(), 100 * MS);
    assert_eq!(c.level(), 3);
    let c = Controller::new(ladder(), MS / 10);
    assert_eq!(c.level(), 0, "nothing fits: the cheapest");
    let c = Controller::new(Vec::new(), MS);
    assert_eq!(c.levels().len(), 1);
}

#[test]
fn a_late_frame_steps_down_at_once_and_headroom_climbs_one_level_at_a_time() {
    let mut c = Controller::new(ladder(), 10 * MS);
    assert_eq!(c.level(), 3);
    for _ in 0..Controller::CALM {
        c.observe(5 * MS);
    }
    assert_eq!(c.level(), 3, "5 of 10 ms: stays");
    // A spike after the level held.
    c.observe(12 * MS);
    // 12 ms at 5 ms's reference: ×2.4; refine:3 would take 7.2 (85 % is
    // 8.5), so one level down.
    assert_eq!(c.level(), 2);
    // Back to normal: refine:3 at 3 ms climbs after the run with headroom
    // (doubled for the failure above), one level: a spike after a level
    // held does not make its time look higher.
    let mut frames = 0;
    while c.level() == 2 {
        c.observe(3 * MS);
        frames += 1;
        assert!(frames < 200, "never climbed");
    }
    assert_eq!(c.level(), 3);
    assert!(frames >= 2 * Controller::UP_RUN as usize, "{frames}");
    assert!(frames <= 4 * Controller::UP_RUN as usize, "{frames}");
    // A try that fails at once is learnt: the level is not tried again
    // for a calm period.
    c.observe(12 * MS);
    assert_eq!(c.level(), 2);
    let mut frames = 0;
    while c.level() == 2 && frames < 10 * Controller::CALM {
        c.observe(3 * MS);
        frames += 1;
    }
    assert!(
        frames > Controller::CALM,
        "tried again after {frames} frames"
    );
    assert_eq!(c.level(), 3, "tried again in the end");
    assert_eq!(c.counts()[3].left_late, 2);
    assert_eq!(c.counts()[3].switches_in, 2);
}

#[test]
fn the_budget_is_the_refresh_less_the_presents_lead_and_a_32nd() {
    assert_eq!(frame_budget_ns(32_000, 2_000), 29_000);
    // A lead over half a period (the present loop warming up) counts as half.
    assert_eq!(frame_budget_ns(32_000, 40_000), 15_000);
    assert_eq!(frame_budget_ns(1, 5_000), 1, "never zero");
}

#[test]
fn the_pareto_front_drops_levels_no_better_than_a_cheaper_one() {
    let levels = vec![
        level("none", MS / 10, Some(20.5)),
        level("wiener", MS, Some(21.6)),
        // Slower and worse than the Wiener: dropped.
        level("refine:1", 2 * MS, Some(21.4)),
        level("refine:10", 5 * MS, Some(22.0)),
        // Not measured: kept.
        level("half", 6 * MS, None),
        // Slower than refine:10 and worse.
        level("model", 7 * MS, Some(21.6)),
    ];
    let kept: Vec<&str> = pareto_front(&levels)
        .into_iter()
        .map(|i| levels[i].name.as_str())
        .collect();
    assert_eq!(kept, ["none", "wiener", "refine:10", "half"]);
}

/// The service updates its report every frame in place: it says what a
/// report made afresh says, and a report of other levels is remade.
#[test]
fn a_report_updated_in_place_is_the_report_made_afresh() {
    let mut c = Controller::new(ladder(), 10 * MS);
    let mut report = BudgetReport::of(&c);
    report.dropped = vec!["refine:1".into()];
    for t in [5, 12, 3, 3, 4, 12, 2] {
        c.observe(t * MS);
        report.update(&c);
        let fresh = BudgetReport {
            dropped: vec!["refine:1".into()],
            ..BudgetReport::of(&c)
        };
        assert_eq!(report, fresh);
    }
    assert!(report.quality_delivered_db.is_some());
    let other = Controller::new(ladder()[..2].to_vec(), 10 * MS);
    report.update(&other);
    assert_eq!(report.levels.len(), 2);
    assert_eq!(report.dropped, ["refine:1"]);
}
