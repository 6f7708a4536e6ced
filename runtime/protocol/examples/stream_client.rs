//! Streams frames to a running `nedrt run --source socket` over the
//! socket protocol (docs/protocol.md): a moving test pattern as RGBA8
//! (sRGB-encoded, as a typical render target), stamped with CLOCK_MONOTONIC
//! capture times, at a given rate. Prints each rejection and a summary.
//!
//! With `--overlay` it speaks protocol version 2: it sets a translucent
//! quad layer (a HUD bar, premultiplied RGBA8, centred near the bottom,
//! redrawn once a second) over its frames, and reports how far ahead of
//! their predicted display time its frames were submitted. With `--stereo`
//! (version 2, a service run with `--stereo`) it sends each eye its own
//! frame, the right eye's bar a few pixels to the left (it floats in front),
//! and with `--overlay` a HUD on each eye.
//!
//! ```sh
//! nedrt run --source socket --socket /tmp/nedrt.sock &
//! cargo run --release --example stream_client -- /tmp/nedrt.sock 600 90
//! cargo run --release --example stream_client -- /tmp/nedrt.sock 600 90 --overlay
//! cargo run --release --example stream_client -- /tmp/nedrt.sock 600 90 --stereo --overlay
//! ```

use std::path::PathBuf;
use std::time::{Duration, Instant};

use nedrt_protocol::PixelFormat;
use nedrt_protocol::Placement;
use nedrt_protocol::monotonic_ns;
use nedrt_protocol::test_pattern::{pattern_rgba8, pattern_rgba8_shifted, stereo_disparity_px};
use nedrt_protocol::v2::ALL_VIEWS;
use nedrt_protocol::v2::{HeaderV2, QuadFormat};
use nedrt_protocol::{Client, DEFAULT_SHM_DIR, FrameHeader, STATUS_OK};

/// The HUD bar: a dark translucent band with a bright bar growing with
/// `second`, premultiplied.
fn hud(w: usize, h: usize, second: u64) -> Vec<u8> {
    let filled = (second as usize * w / 10) % (w + 1);
    (0..w * h)
        .flat_map(|i| {
            let (x, y) = (i % w, i / w);
            let edge = y < 2 || y + 2 >= h || x < 2 || x + 2 >= w;
            if edge || x < filled {
                [200, 200, 200, 220]
            } else {
                [10, 10, 20, 96]
            }
        })
        .collect()
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let overlay = args.iter().any(|a| a == "--overlay");
    let stereo = args.iter().any(|a| a == "--stereo");
    let mut args = args
        .into_iter()
        .filter(|a| a != "--overlay" && a != "--stereo");
    let socket = PathBuf::from(args.next().unwrap_or_else(|| "/tmp/nedrt.sock".into()));
    let frames: u64 = args.next().map_or(Ok(300), |a| a.parse())?;
    let rate_hz: f64 = args.next().map_or(Ok(90.0), |a| a.parse())?;

    let (w, h) = {
        // The panel's size comes with the welcome; size the memory for it.
        let probe = Client::connect(&socket, DEFAULT_SHM_DIR.as_ref(), 0)?;
        probe.panel
    };
    let frame_bytes = w * h * PixelFormat::Rgba8Srgb.bytes_per_pixel();
    // The HUD: a quarter of the width, 1/12 of the height, after the frame.
    let (hud_w, hud_h) = ((w / 4).max(8), (h / 12).max(6));
    let bytes = frame_bytes + if overlay { 4 * hud_w * hud_h } else { 0 };
    let mut client = if overlay || stereo {
        Client::connect_v2(&socket, DEFAULT_SHM_DIR.as_ref(), bytes as u64)?
    } else {
        Client::connect(&socket, DEFAULT_SHM_DIR.as_ref(), bytes as u64)?
    };
    println!(
        "connected (protocol version {}): panel {w}×{h}; streaming {frames} frames at {rate_hz} Hz",
        client.version
    );
    // The eyes: where the welcome says the views are (one: the panel).
    let views: Vec<[usize; 4]> = if stereo {
        if client.views.len() != 2 {
            return Err(format!(
                "--stereo: the service runs {} view(s); start it with `nedrt run --stereo`",
                client.views.len().max(1)
            )
            .into());
        }
        client.views.clone()
    } else {
        vec![[0, 0, w, h]]
    };
    let start = Instant::now();
    let mut rejected = 0;
    // Version 2: how far ahead of the predicted refresh each frame went.
    let mut lead_ms = Vec::new();
    for id in 0..frames {
        let due = start + Duration::from_secs_f64(id as f64 / rate_hz);
        std::thread::sleep(due.saturating_duration_since(Instant::now()));
        let pixels = pattern_rgba8(w, h, id, rate_hz);
        let second = (id as f64 / rate_hz) as u64;
        // Once a second (the first frame of each): a quad stays until replaced.
        let redraw_hud = overlay && (id == 0 || ((id - 1) as f64 / rate_hz) as u64 != second);
        let reply = if overlay || stereo {
            if overlay && redraw_hud {
                // A HUD on every view the service runs, placed in each.
                let hud_views: Vec<[usize; 4]> = if client.views.is_empty() {
                    vec![[0, 0, w, h]]
                } else {
                    client.views.clone()
                };
                for (v, &[_, _, vw, vh]) in hud_views.iter().enumerate() {
                    let (hud_w, hud_h) = ((vw / 4).max(8).min(vw), (vh / 12).max(6).min(vh));
                    let quad = HeaderV2::quad(
                        v as u8,
                        1,
                        1,
                        Placement::Pixels {
                            x: ((vw - hud_w) / 2) as i64,
                            y: (vh - hud_h - vh / 20) as i64,
                        },
                        QuadFormat::Rgba8Premultiplied,
                        (hud_w, hud_h),
                        id,
                        frame_bytes as u64,
                    );
                    let r = client.send_v2(&quad, &hud(hud_w, hud_h, second))?;
                    if r.reply.status != STATUS_OK {
                        eprintln!(
                            "HUD refused (status {}): {}",
                            r.reply.status, r.reply.message
                        );
                    }
                }
            }
            let mut last = None;
            for (v, &[_, _, vw, vh]) in views.iter().enumerate() {
                let predicted = client.timing.as_ref().map(|t| t.predicted_display_ns);
                let now = monotonic_ns();
                if let Some(p) = predicted {
                    lead_ms.push((p as f64 - now as f64) / 1e6);
                }
                let (view, pixels) = if stereo {
                    let shift = v * stereo_disparity_px(vw);
                    (v as u8, pattern_rgba8_shifted(vw, vh, id, rate_hz, shift))
                } else if client.views.len() > 1 {
                    // One panel-sized frame for every view.
                    (ALL_VIEWS, pixels.clone())
                } else {
                    (0, pixels.clone())
                };
                // Each eye's frame its own id (recordings name frames by id).
                let frame_id = if stereo { 2 * id + v as u64 } else { id };
                let header =
                    HeaderV2::projection(view, PixelFormat::Rgba8Srgb, (vw, vh), frame_id, now);
                last = Some(client.send_v2(&header, &pixels)?.reply);
            }
            last.ok_or("no view")?
        } else {
            let header = FrameHeader::new(PixelFormat::Rgba8Srgb, w, h, id, monotonic_ns());
            client.send(&header, &pixels)?
        };
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
    if !lead_ms.is_empty() {
        lead_ms.sort_by(f64::total_cmp);
        let q = |p: f64| lead_ms[((lead_ms.len() - 1) as f64 * p) as usize];
        println!(
            "submitted ahead of the predicted display time: p50 {:.1} ms, p10 {:.1}, p90 {:.1}",
            q(0.5),
            q(0.1),
            q(0.9)
        );
    }
    Ok(())
}
