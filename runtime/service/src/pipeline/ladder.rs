//! The frame budget (issue 54): the ladder of preprocessing levels a run
//! can afford, and the controller that picks, frame by frame, the best
//! level whose time fits the refresh.
//!
//! A compositor's first promise is the refresh: rather than drop frames
//! when its preprocessing does not fit, the service steps down to a
//! cheaper level, and climbs back when the time is there again, as
//! renderers scale their quality to the budget (Valve's The Lab keeps a
//! ring of GPU times with thresholds at 70, 85 and 90 % of the frame;
//! Unreal's dynamic resolution has a panic rule for a frame over budget
//! and changes otherwise only after a history of frames).
//!
//! The rules ([`Controller::observe`]):
//! - a frame over the budget steps down at once (the panic rule), to the
//!   best level that frame's time predicts will fit;
//! - a level predicted late (its learnt mean plus two deviations over the
//!   budget) steps down the same way;
//! - a run of frames under [`Controller::UP_BELOW`] of the budget climbs
//!   one level, when that level is predicted to fit with room to spare;
//!   the run doubles for each time that level was left for being late
//!   (halved again after a second of calm), so a load that sits at a
//!   level's boundary does not make the ladder oscillate;
//! - only the stage's own time counts, not the wait for a present or a
//!   late application: a miss the preprocessing did not cause does not
//!   lower the level.
//!
//! The levels' times scale together: the time of a level not running is
//! predicted from the one running, by the ratio of their start-up times
//! (each level's [`Level::reference_ns`]). A GPU slowed by heat or another
//! application slows every level alike; a level's own cost differs from
//! another's by its work.
//!
//! Every view of a frame runs the same level: two eyes at different
//! sharpness is binocular rivalry, not a saving. The budget is the whole
//! frame's, every view's work in it.

mod levels;

pub use levels::{DeviceLevels, HostLevels, Levels, Selection, Unprocessed};

/// One level of the ladder.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Level {
    /// Its name, as `--preprocess auto:LO..HI` takes it: none, wiener,
    /// refine:K, a network's.
    pub name: String,
    /// The quality it delivers, where the tradeoff study measured it: the
    /// mean PSNR against the sharp image over 0–2.5 D (dB).
    pub quality_db: Option<f64>,
    /// Its time per frame on this machine, measured at start-up (ns):
    /// the scale other levels' predictions transfer by.
    pub reference_ns: u64,
}

/// The ladder a service runs: its levels, cheapest first (a
/// `reference_ns` of 0 is measured at start-up, [`super::service::Service::start`]),
/// and the selection every view's engine follows ([`HostLevels`],
/// [`DeviceLevels`]).
#[derive(Debug, Clone)]
pub struct Ladder {
    pub levels: Vec<Level>,
    pub selection: Selection,
}

/// What the frame budget did in a run: the report's section.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct BudgetReport {
    /// The budget of a frame's preprocessing when last set (ms).
    pub budget_ms: f64,
    /// The level the next frame runs.
    pub level_now: String,
    pub levels: Vec<LevelReport>,
    /// The mean quality of the frames run, each weighted by the frames at
    /// its level (dB; where every level run has a quality).
    pub quality_delivered_db: Option<f64>,
    /// Levels measured and left out: no better than a faster one.
    pub dropped: Vec<String>,
}

/// The mean quality of the frames run, each weighted by the frames at its
/// level (where every level run has a quality).
fn delivered(levels: &[LevelReport]) -> Option<f64> {
    let frames: u64 = levels.iter().map(|l| l.frames).sum();
    let weighted = levels
        .iter()
        .filter(|l| l.frames > 0)
        .map(|l| l.quality_db.map(|q| q * l.frames as f64))
        .sum::<Option<f64>>()?;
    (frames > 0).then(|| weighted / frames as f64)
}

/// One level's line of the [`BudgetReport`].
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LevelReport {
    pub name: String,
    pub quality_db: Option<f64>,
    /// Its start-up time (ms).
    pub reference_ms: f64,
    pub frames: u64,
    /// Mean time of its frames (ms).
    pub mean_ms: Option<f64>,
    pub switches_in: u64,
    pub left_late: u64,
}

impl BudgetReport {
    /// Brings the report up to `c` in place (a frame's update: the levels'
    /// names are kept, nothing is allocated); a report of other levels is
    /// made afresh.
    pub fn update(&mut self, c: &Controller) {
        let same = self.levels.len() == c.levels().len()
            && self
                .levels
                .iter()
                .zip(c.levels())
                .all(|(r, l)| r.name == l.name);
        if !same {
            let dropped = std::mem::take(&mut self.dropped);
            *self = Self::of(c);
            self.dropped = dropped;
            return;
        }
        for (r, (l, n)) in self
            .levels
            .iter_mut()
            .zip(c.levels().iter().zip(c.counts()))
        {
            r.quality_db = l.quality_db;
            r.reference_ms = l.reference_ns as f64 / 1e6;
            r.frames = n.frames;
            r.mean_ms = (n.frames > 0).then(|| n.time_ns as f64 / n.frames as f64 / 1e6);
            r.switches_in = n.switches_in;
            r.left_late = n.left_late;
        }
        self.budget_ms = c.budget_ns() as f64 / 1e6;
        self.level_now.clone_from(&c.levels()[c.level()].name);
        self.quality_delivered_db = delivered(&self.levels);
    }

    pub fn of(c: &Controller) -> Self {
        let levels: Vec<LevelReport> = c
            .levels()
            .iter()
            .zip(c.counts())
            .map(|(l, n)| LevelReport {
                name: l.name.clone(),
                quality_db: l.quality_db,
                reference_ms: l.reference_ns as f64 / 1e6,
                frames: n.frames,
                mean_ms: (n.frames > 0).then(|| n.time_ns as f64 / n.frames as f64 / 1e6),
                switches_in: n.switches_in,
                left_late: n.left_late,
            })
            .collect();
        let quality_delivered_db = delivered(&levels);
        Self {
            budget_ms: c.budget_ns() as f64 / 1e6,
            level_now: c.levels()[c.level()].name.clone(),
            levels,
            quality_delivered_db,
            dropped: Vec::new(),
        }
    }

    /// The report's lines: the budget, then a level a line.
    pub fn table(&self) -> String {
        let quality = |q: Option<f64>| q.map_or("–".into(), |q| format!("{q:.2} dB"));
        let mut s = format!(
            "frame budget: {:.2} ms a frame, now at {}; quality delivered {}
",
            self.budget_ms,
            self.level_now,
            quality(self.quality_delivered_db)
        );
        if !self.dropped.is_empty() {
            s += &format!(
                "  left out (no better than a faster level): {}\n",
                self.dropped.join(", ")
            );
        }
        for l in &self.levels {
            s += &format!(
                "  {:<12} quality {:>9}  start-up {:>8.3} ms  {:>6} frames  mean {:>8}  {} switches in, {} left late\n",
                l.name,
                quality(l.quality_db),
                l.reference_ms,
                l.frames,
                l.mean_ms.map_or("–".into(), |m| format!("{m:.3} ms")),
                l.switches_in,
                l.left_late
            );
        }
        s
    }
}

/// What the controller did at one level.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct LevelCounts {
    /// Frames run at the level.
    pub frames: u64,
    /// Their time, summed (ns).
    pub time_ns: u64,
    /// Switches to the level.
    pub switches_in: u64,
    /// Switches away from it for a frame late or predicted late.
    pub left_late: u64,
}

/// Picks each frame's level ([module docs](self)).
#[derive(Debug, Clone)]
pub struct Controller {
    levels: Vec<Level>,
    budget_ns: u64,
    current: usize,
    /// The current level's learnt time: mean and mean deviation (the
    /// gains of [`super::pacing::Estimate`]'s running average).
    mean_ns: f64,
    dev_ns: f64,
    /// Frames run since the last switch.
    since_switch: u64,
    /// Frames in a row under [`Controller::UP_BELOW`] of the budget.
    headroom_run: u64,
    /// Per level: its reference as learnt (ns): the start-up time, or
    /// what it took when last left for being late, scaled to the level it
    /// left for; drifting back to the start-up time in calm periods.
    reference_ns: Vec<f64>,
    /// A level left for being late and its time then, until the level
    /// stepped down to has settled and the ratio is learnt.
    pending: Option<(usize, f64)>,
    /// Per level: recent failures (left for being late), one forgiven per
    /// [`Controller::CALM`] frames without a step down.
    failures: Vec<u32>,
    /// Per level: what its next failed try adds to its failures (doubled
    /// by each, back to 1 once it held for a calm period).
    backoff: Vec<u32>,
    /// Frames since the last step down.
    calm: u64,
    counts: Vec<LevelCounts>,
}

impl Controller {
    /// A frame predicted at most this share of the budget is one a level
    /// may be chosen for (Valve's 85 %).
    pub const FIT: f64 = 0.85;
    /// Frames under this share of the budget count toward a climb (Valve's 70 %).
    pub const UP_BELOW: f64 = 0.7;
    /// Frames with headroom before a climb, times 2 for each recent failure
    /// of the level above.
    pub const UP_RUN: u64 = 8;
    /// Frames after a switch before the next climb: they still show the
    /// old level's queue (Valve waits out two).
    pub const SETTLE: u64 = 2;
    /// Frames without a step down after which each level forgives one
    /// failure, and a level with none left drifts halfway back to its
    /// start-up time (a second at 90 Hz).
    pub const CALM: u64 = 90;
    /// Most failures a level keeps: its climb's run is at most
    /// `UP_RUN << MAX_FAILURES` frames, its wait at most that many calm
    /// periods.
    pub const MAX_FAILURES: u32 = 16;
    /// Deviations above its mean a level is predicted to take.
    pub const DEVIATIONS: f64 = 2.0;

    /// A controller over `levels`, cheapest first, each better than the
    /// one before, starting at the best level whose start-up time fits.
    /// An empty ladder gets one level of no work.
    pub fn new(mut levels: Vec<Level>, budget_ns: u64) -> Self {
        if levels.is_empty() {
            levels.push(Level {
                name: "none".into(),
                quality_db: None,
                reference_ns: 0,
            });
        }
        let n = levels.len();
        let reference_ns = levels.iter().map(|l| l.reference_ns as f64).collect();
        let mut c = Self {
            levels,
            budget_ns: budget_ns.max(1),
            current: 0,
            mean_ns: 0.0,
            dev_ns: 0.0,
            since_switch: 0,
            headroom_run: 0,
            reference_ns,
            pending: None,
            failures: vec![0; n],
            backoff: vec![1; n],
            calm: 0,
            counts: vec![LevelCounts::default(); n],
        };
        let start = c.best_fitting(1.0, n - 1);
        c.enter(start, c.reference_ns[start], 0.0);
        c.counts[start].switches_in = 0;
        c
    }

    pub fn levels(&self) -> &[Level] {
        &self.levels
    }

    /// The level the next frame runs.
    pub fn level(&self) -> usize {
        self.current
    }

    pub fn budget_ns(&self) -> u64 {
        self.budget_ns
    }

    /// The budget changes as the present's lead is learnt.
    pub fn set_budget_ns(&mut self, budget_ns: u64) {
        self.budget_ns = budget_ns.max(1);
    }

    pub fn counts(&self) -> &[LevelCounts] {
        &self.counts
    }

    /// The predicted time of level `j` (ns): its reference scaled as the
    /// current level's learnt time is to its own reference.
    pub fn predicted_ns(&self, j: usize) -> f64 {
        self.scaled(j, self.mean_ns + Self::DEVIATIONS * self.dev_ns)
    }

    /// Level `j`'s time when the current level takes `current_ns`.
    fn scaled(&self, j: usize, current_ns: f64) -> f64 {
        current_ns * self.reference_ns[j] / self.reference_ns[self.current].max(1.0)
    }

    /// The best level up to `highest` predicted within `FIT` of the budget
    /// when its reference is scaled by `scale`; else the cheapest.
    fn best_fitting(&self, scale: f64, highest: usize) -> usize {
        let fit = Self::FIT * self.budget_ns as f64;
        (0..=highest)
            .rev()
            .find(|&j| self.reference_ns[j] * scale <= fit)
            .unwrap_or(0)
    }

    fn enter(&mut self, j: usize, mean_ns: f64, dev_ns: f64) {
        if j != self.current {
            self.counts[j].switches_in += 1;
            tracing::debug!(
                "frame budget: {} → {}",
                self.levels[self.current].name,
                self.levels[j].name
            );
        }
        self.current = j;
        self.mean_ns = mean_ns;
        self.dev_ns = dev_ns;
        self.since_switch = 0;
        self.headroom_run = 0;
    }

    /// Steps down from the current level, whose time is `current_ns`, to
    /// the best cheaper level predicted to fit.
    fn step_down(&mut self, current_ns: f64) {
        let from = self.current;
        let own = self.reference_ns[from].max(1.0);
        let to = match from {
            0 => 0,
            _ => self.best_fitting(current_ns / own, from - 1),
        };
        self.calm = 0;
        if to == from {
            return;
        }
        self.counts[from].left_late += 1;
        if self.since_switch >= Self::CALM {
            // The level had held: a load that came (or a spike), which the
            // ratio of the levels' times covers; tried again soon.
            self.failures[from] = self.failures[from].max(1);
            self.backoff[from] = 1;
        } else {
            // A try that failed: the level costs more than its reference
            // says. What it took is learnt against the level it leaves
            // for, and the next try waits twice as long.
            self.failures[from] =
                (self.failures[from] + self.backoff[from]).min(Self::MAX_FAILURES);
            self.backoff[from] = (2 * self.backoff[from]).min(Self::MAX_FAILURES);
            self.pending = Some((from, current_ns));
        }
        let ratio = self.reference_ns[to] / own;
        self.enter(to, current_ns * ratio, self.dev_ns * ratio);
    }

    /// The frame just run at [`Controller::level`] took `ns` of the
    /// stage's own time; decides the next frame's level.
    pub fn observe(&mut self, ns: u64) {
        let j = self.current;
        self.counts[j].frames += 1;
        self.counts[j].time_ns += ns;
        self.since_switch += 1;
        self.calm += 1;
        if self.calm.is_multiple_of(Self::CALM) {
            self.forgive();
        }
        let t = ns as f64;
        if self.since_switch == 1 {
            // The first frame at a level replaces its prediction.
            self.dev_ns = (self.dev_ns + (t - self.mean_ns).abs()) / 2.0;
            self.mean_ns = t;
        } else {
            self.dev_ns = (3.0 * self.dev_ns + (t - self.mean_ns).abs()) / 4.0;
            self.mean_ns = (7.0 * self.mean_ns + t) / 8.0;
        }
        if self.since_switch == Self::SETTLE
            && let Some((left, left_ns)) = self.pending.take()
        {
            // The level left took `left_ns` where this one takes its mean:
            // their ratio, as measured now.
            self.reference_ns[left] = self.reference_ns[j] * left_ns / self.mean_ns.max(1.0);
        }
        let budget = self.budget_ns as f64;
        if t > budget {
            // Late: the panic rule, by this frame's time.
            self.step_down(t);
            return;
        }
        let predicted = self.mean_ns + Self::DEVIATIONS * self.dev_ns;
        if self.since_switch > 1 && predicted > budget {
            self.step_down(self.mean_ns);
            return;
        }
        if t < Self::UP_BELOW * budget {
            self.headroom_run += 1;
        } else {
            self.headroom_run = 0;
        }
        let up = j + 1;
        if up >= self.levels.len() || self.since_switch < Self::SETTLE {
            return;
        }
        let needed = Self::UP_RUN << self.failures[up].min(4);
        if self.headroom_run >= needed && self.predicted_ns(up) <= Self::FIT * budget {
            let (mean, dev) = (self.scaled(up, self.mean_ns), self.scaled(up, self.dev_ns));
            self.enter(up, mean, dev);
        }
    }
}

impl Controller {
    /// A calm period: each level forgives a failure, and one without any
    /// drifts halfway back to its start-up time (a load that lifted); the
    /// level running has held, so its tries start afresh.
    fn forgive(&mut self) {
        if self.since_switch >= Self::CALM {
            self.backoff[self.current] = 1;
        }
        for (j, f) in self.failures.iter_mut().enumerate() {
            if *f > 0 {
                *f -= 1;
            } else {
                let start = self.levels[j].reference_ns as f64;
                self.reference_ns[j] = (self.reference_ns[j] + start) / 2.0;
            }
        }
    }
}

/// The budget of a frame's preprocessing (ns): the refresh period less
/// the present's lead (its work and margin, before each refresh) and a
/// 32nd of the period to spare, as the pacing plans a submission. A lead
/// over half a period counts as half: that is the present loop's warm-up
/// (its first presents pay one-time costs), and a budget of nothing then
/// would drop every view to the lowest level on it.
pub fn frame_budget_ns(period_ns: u64, present_lead_ns: u64) -> u64 {
    period_ns
        .saturating_sub(present_lead_ns.min(period_ns / 2))
        .saturating_sub(period_ns / 32)
        .max(1)
}

/// Drops every level no better than one at most as slow: what remains is
/// the Pareto front of time against quality, in the given order (each
/// level meant to be better than the one before). A level whose quality
/// is not known is kept. Returns the kept levels' indices in `levels`.
pub fn pareto_front(levels: &[Level]) -> Vec<usize> {
    (0..levels.len())
        .filter(|&i| {
            let Some(q) = levels[i].quality_db else {
                return true;
            };
            !levels.iter().enumerate().any(|(j, other)| {
                j != i
                    && other.reference_ns <= levels[i].reference_ns
                    && other.quality_db.is_some_and(|o| o > q || (o == q && j < i))
            })
        })
        .collect()
}

#[cfg(test)]
#[path = "ladder_tests.rs"]
mod tests;
