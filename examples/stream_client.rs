//! Streams frames to a running `nedrt run --source socket` over the
//! socket protocol (docs/protocol.md): a moving test pattern as RGBA8
//! (sRGB-encoded, as a typical render target), stamped with CLOCK_MONOTONIC
//! capture times, at a given rate. Prints each rejection and a summary.
//!
//! ```sh
//! nedrt run --source socket --socket /tmp/nedrt.sock &
//! cargo run --release --example stream_client -- /tmp/nedrt.sock 600 90
//! ```

use std::path::PathBuf;
use std::time::{Duration, Instant};

use nedrt_service::pipeline::frame::PixelFormat;
use nedrt_service::pipeline::pacing::monotonic_ns;
use nedrt_service::pipeline::protocol::{Client, DEFAULT_SHM_DIR, FrameHeader, STATUS_OK};
use nedrt_service::pipeline::source::pattern::pattern_rgba8;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let socket = PathBuf::from(args.next().unwrap_or_else(|| "/tmp/nedrt.sock".into()));
    let frames: u64 = args.next().map_or(Ok(300), |a| a.parse())?;
    let rate_hz: f64 = args.next().map_or(Ok(90.0), |a| a.parse())?;

    let (w, h) = {
        // The panel's size comes with the welcome; size the memory for it.
        let probe = Client::connect(&socket, DEFAULT_SHM_DIR.as_ref(), 0)?;
        probe.panel
    };
    let bytes = w * h * PixelFormat::Rgba8Srgb.bytes_per_pixel();
    let mut client = Client::connect(&socket, DEFAULT_SHM_DIR.as_ref(), bytes as u64)?;
    println!("connected: panel {w}×{h}; streaming {frames} frames at {rate_hz} Hz");
    let start = Instant::now();
    let mut rejected = 0;
    for id in 0..frames {
        let due = start + Duration::from_secs_f64(id as f64 / rate_hz);
        std::thread::sleep(due.saturating_duration_since(Instant::now()));
        let pixels = pattern_rgba8(w, h, id, rate_hz);
        let header = FrameHeader::new(PixelFormat::Rgba8Srgb, w, h, id, monotonic_ns());
        let reply = client.send(&header, &pixels)?;
        if reply.status != STATUS_OK {
            rejected += 1;
            eprintln!(
                "frame {id} rejected (status {}): {}",
                reply.status, reply.message
            );
        }
    }
    println!(
        "sent {frames} frames in {:.2} s, {rejected} rejected",
        start.elapsed().as_secs_f64()
    );
    Ok(())
}
