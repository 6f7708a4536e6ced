//! How long the test pattern takes to draw, per frame size (the pattern
//! source makes one a refresh, so a drawing longer than a period skips
//! refreshes; docs/benchmarks.md). Usage:
//! `cargo run --release -p nedrt-protocol --example pattern_time [FRAMES]`.

use nedrt_protocol::test_pattern::pattern_rgba8;

fn main() {
    let frames: usize = match std::env::args().nth(1).map(|a| a.parse()) {
        None => 20,
        Some(Ok(n)) if n > 0 => n,
        Some(_) => {
            eprintln!("pattern_time: FRAMES must be a whole number above 0");
            std::process::exit(2);
        }
    };
    for (w, h) in [(480usize, 270usize), (1920, 1080)] {
        let mut ms: Vec<f64> = (0..frames as u64)
            .map(|id| {
                let t = std::time::Instant::now();
                std::hint::black_box(pattern_rgba8(w, h, id, 90.0));
                t.elapsed().as_secs_f64() * 1e3
            })
            .collect();
        ms.sort_by(f64::total_cmp);
        println!(
            "{w}×{h}: {frames} frames, min {:.2} ms, median {:.2} ms, max {:.2} ms",
            ms[0],
            ms[frames / 2],
            ms[frames - 1]
        );
    }
}
