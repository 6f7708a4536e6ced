//! Latency accounting: a fixed-size log-bucketed histogram per stage (no
//! allocation per sample, so it can sit on a real-time thread) reporting
//! p50, p99 and max in nanoseconds.

/// Buckets per power of two: 128 gives ≤ 0.8 % relative bucket width, so a
/// reported percentile is within 1 % of the exact one (8, before, read
/// "16.8 ms" for anything in 15.7–16.8).
const SUB: u32 = 128;
/// Covers 1 ns … 2^40 ns (≈ 18 min).
const OCTAVES: u32 = 40;
const BUCKETS: usize = (OCTAVES * SUB) as usize;

/// A latency histogram in nanoseconds.
#[derive(Debug, Clone)]
pub struct Histogram {
    counts: Vec<u64>,
    count: u64,
    max_ns: u64,
    sum_ns: u128,
}

impl Default for Histogram {
    fn default() -> Self {
        Self::new()
    }
}

fn bucket(ns: u64) -> usize {
    let ns = ns.max(1);
    let octave = 63 - ns.leading_zeros();
    // The SUB linear steps inside [2^octave, 2^(octave+1)).
    let frac = if octave >= SUB.trailing_zeros() {
        ((ns >> (octave - SUB.trailing_zeros())) as u32) & (SUB - 1)
    } else {
        ((ns << (SUB.trailing_zeros() - octave)) as u32) & (SUB - 1)
    };
    ((octave * SUB + frac) as usize).min(BUCKETS - 1)
}

/// The upper edge of a bucket, in ns: what a percentile reports.
fn bucket_upper_ns(b: usize) -> u64 {
    let octave = b as u32 / SUB;
    let frac = b as u64 % SUB as u64;
    let base = 1u64 << octave;
    base + (base * (frac + 1)) / SUB as u64
}

impl Histogram {
    pub fn new() -> Self {
        Self {
            counts: vec![0; BUCKETS],
            count: 0,
            max_ns: 0,
            sum_ns: 0,
        }
    }

    pub fn record_ns(&mut self, ns: u64) {
        self.counts[bucket(ns)] += 1;
        self.count += 1;
        self.max_ns = self.max_ns.max(ns);
        self.sum_ns += ns as u128;
    }

    pub fn count(&self) -> u64 {
        self.count
    }

    pub fn max_ns(&self) -> u64 {
        self.max_ns
    }

    pub fn mean_ns(&self) -> f64 {
        if self.count == 0 {
            0.0
        } else {
            self.sum_ns as f64 / self.count as f64
        }
    }

    /// The `q`-quantile (0…1) as the upper edge of its bucket (an
    /// over-estimate by at most one bucket width, < 1 %), never above the
    /// maximum seen. 0 when empty.
    pub fn quantile_ns(&self, q: f64) -> u64 {
        if self.count == 0 {
            return 0;
        }
        let rank = ((q.clamp(0.0, 1.0) * self.count as f64).ceil() as u64).max(1);
        let mut seen = 0;
        for (b, &c) in self.counts.iter().enumerate() {
            seen += c;
            if seen >= rank {
                return bucket_upper_ns(b).min(self.max_ns);
            }
        }
        self.max_ns
    }

    pub fn merge(&mut self, other: &Histogram) {
        for (a, b) in self.counts.iter_mut().zip(&other.counts) {
            *a += b;
        }
        self.count += other.count;
        self.max_ns = self.max_ns.max(other.max_ns);
        self.sum_ns += other.sum_ns;
    }

    /// "p50 1.23 ms  p99 4.56 ms  max 7.89 ms  (n = 100)".
    pub fn summary(&self) -> String {
        let ms = |ns: u64| ns as f64 / 1e6;
        format!(
            "p50 {:.3} ms  p99 {:.3} ms  max {:.3} ms  (n = {})",
            ms(self.quantile_ns(0.5)),
            ms(self.quantile_ns(0.99)),
            ms(self.max_ns),
            self.count
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn quantiles_of_a_known_distribution() {
        let mut h = Histogram::new();
        for ms in 1..=100u64 {
            h.record_ns(ms * 1_000_000);
        }
        let p50 = h.quantile_ns(0.5) as f64 / 1e6;
        let p99 = h.quantile_ns(0.99) as f64 / 1e6;
        assert!((50.0..=50.0 * 1.01).contains(&p50), "p50 {p50}");
        assert!((99.0..=100.0).contains(&p99), "p99 {p99}");
        assert_eq!(h.max_ns(), 100_000_000);
        assert_eq!(h.count(), 100);
        assert!((h.mean_ns() - 50.5e6).abs() < 1.0);
        assert_eq!(Histogram::new().quantile_ns(0.5), 0);
    }

    proptest! {
        #[test]
        fn a_quantile_is_never_below_the_true_one_nor_far_above(
            mut samples in proptest::collection::vec(1u64..10_000_000_000, 1..200),
            q in 0.0f64..=1.0,
        ) {
            let mut h = Histogram::new();
            for &s in &samples {
                h.record_ns(s);
            }
            samples.sort_unstable();
            let rank = ((q * samples.len() as f64).ceil() as usize).max(1);
            let truth = samples[rank - 1];
            let got = h.quantile_ns(q);
            prop_assert!(got >= truth.min(h.max_ns()) || got == h.max_ns());
            prop_assert!(got as f64 <= truth as f64 * 1.01 + 1.0, "{got} vs {truth}");
        }

        #[test]
        fn merging_equals_recording_everything_in_one(
            a in proptest::collection::vec(1u64..1_000_000_000, 0..50),
            b in proptest::collection::vec(1u64..1_000_000_000, 0..50),
        ) {
            let (mut ha, mut hb, mut all) = (Histogram::new(), Histogram::new(), Histogram::new());
            a.iter().for_each(|&s| { ha.record_ns(s); all.record_ns(s); });
            b.iter().for_each(|&s| { hb.record_ns(s); all.record_ns(s); });
            ha.merge(&hb);
            prop_assert_eq!(ha.count(), all.count());
            prop_assert_eq!(ha.quantile_ns(0.99), all.quantile_ns(0.99));
            prop_assert_eq!(ha.max_ns(), all.max_ns());
        }
    }
}
