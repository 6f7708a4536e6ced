//! The service's long soak (docs/reliability.md): `nedrt run` on the small
//! test panel (64×48 at 240 Hz, the cpu backend, the headless GPU sink)
//! under a socket client streaming at the panel's rate, with every 50th
//! frame a bad one (NaN, wrong size, malformed header, in turn) and a
//! second client that connects, sends a few frames and leaves every few
//! seconds. Every SAMPLE_S it samples the service's resident memory, its
//! open file descriptors, and the client's reply latency (p50, p99, max
//! over the window); at the end it stops the service with SIGTERM, checks
//! the report's books balance, and writes the samples as JSON and a chart.
//!
//!     cargo build --release && \
//!     cargo run --release --example soak -- [MINUTES] [OUT_DIR]
//!
//! (default 30 minutes into docs/reliability/). Not part of CI.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use nedrt_app::charts::{LinePanel, Panel, Series, series_color, write_figure};
use nedrt_protocol::PixelFormat;
use nedrt_protocol::{Client, FrameHeader, STATUS_OK};

const W: usize = 64;
const H: usize = 48;
const RATE_HZ: f64 = 240.0;
const SAMPLE_S: u64 = 10;
const RECONNECT_EVERY: Duration = Duration::from_secs(3);

#[derive(Debug, serde::Serialize)]
struct Sample {
    t_s: f64,
    rss_kib: u64,
    fds: u64,
    reply_p50_ms: f64,
    reply_p99_ms: f64,
    reply_max_ms: f64,
    frames: u64,
    bad_frames: u64,
    reconnects: u64,
}

fn rss_kib(pid: u32) -> Result<u64> {
    let statm = std::fs::read_to_string(format!("/proc/{pid}/statm"))?;
    let pages: u64 = statm.split_whitespace().nth(1).context("statm")?.parse()?;
    Ok(pages * 4)
}

fn fds(pid: u32) -> Result<u64> {
    Ok(std::fs::read_dir(format!("/proc/{pid}/fd"))?.count() as u64)
}

fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

/// The streaming client: a frame every 1/RATE_HZ, every 50th one bad.
fn stream(
    socket: PathBuf,
    shm: PathBuf,
    stop: Arc<AtomicBool>,
    latencies: Arc<std::sync::Mutex<Vec<f64>>>,
    counts: Arc<[AtomicU64; 2]>,
) -> Result<()> {
    let mut client = Client::connect(&socket, &shm, (W * H * 4) as u64)?;
    let period = Duration::from_secs_f64(1.0 / RATE_HZ);
    let mut next = Instant::now();
    let good: Vec<u8> = (0..W * H * 4).map(|i| (i * 5 % 256) as u8).collect();
    let mut id = 0u64;
    while !stop.load(Ordering::Relaxed) {
        next += period;
        if let Some(wait) = next.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        id += 1;
        let t0 = Instant::now();
        let reply = if id.is_multiple_of(50) {
            counts[1].fetch_add(1, Ordering::Relaxed);
            match (id / 50) % 3 {
                0 => client.send_header_bytes(&[0u8; 48])?,
                1 => client.send(
                    &FrameHeader::new(PixelFormat::Rgba8Linear, W + 1, H, id, 0),
                    &good,
                )?,
                _ => {
                    let mut h = FrameHeader::new(PixelFormat::Rgba8Linear, W, H, id, 0);
                    h.length += 1;
                    client.send(&h, &good)?
                }
            }
        } else {
            client.send(
                &FrameHeader::new(PixelFormat::Rgba8Srgb, W, H, id, 0),
                &good,
            )?
        };
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        if !id.is_multiple_of(50) && reply.status != STATUS_OK {
            bail!("frame {id} refused: {}", reply.message);
        }
        counts[0].fetch_add(1, Ordering::Relaxed);
        latencies.lock().unwrap_or_else(|p| p.into_inner()).push(ms);
    }
    Ok(())
}

/// The reconnecting client: connects, sends three frames, leaves.
fn churn(
    socket: PathBuf,
    shm: PathBuf,
    stop: Arc<AtomicBool>,
    reconnects: Arc<AtomicU64>,
) -> Result<()> {
    let payload = vec![128u8; W * H * 4];
    while !stop.load(Ordering::Relaxed) {
        let mut c = Client::connect(&socket, &shm, payload.len() as u64)?;
        for k in 0..3 {
            let r = c.send(
                &FrameHeader::new(PixelFormat::Rgba8Linear, W, H, 1_000_000 + k, 0),
                &payload,
            )?;
            if r.status != STATUS_OK {
                bail!("reconnecting client refused: {}", r.message);
            }
        }
        drop(c);
        reconnects.fetch_add(1, Ordering::Relaxed);
        std::thread::sleep(RECONNECT_EVERY);
    }
    Ok(())
}

fn chart(samples: &[Sample], out: &Path) -> Result<()> {
    let t_max = samples.last().map_or(1.0, |s| s.t_s).max(1.0) / 60.0;
    let line = |name: &str, i: usize, f: &dyn Fn(&Sample) -> f64| Series {
        name: name.into(),
        color: series_color(i),
        dashed: false,
        points: samples.iter().map(|s| (s.t_s / 60.0, f(s))).collect(),
    };
    let top = |v: &mut dyn Iterator<Item = f64>| v.fold(0.0f64, f64::max) * 1.2 + 1e-9;
    let rss = line("RSS (MiB)", 0, &|s| s.rss_kib as f64 / 1024.0);
    let fd = line("open descriptors", 1, &|s| s.fds as f64);
    let p50 = line("reply p50", 2, &|s| s.reply_p50_ms);
    let p99 = line("reply p99", 3, &|s| s.reply_p99_ms);
    let panels = vec![
        Panel::Lines(LinePanel {
            title: "Service resident memory".into(),
            x_label: "minutes".into(),
            y_label: "MiB".into(),
            x_range: (0.0, t_max),
            y_range: (0.0, top(&mut rss.points.iter().map(|p| p.1))),
            series: vec![rss],
            legend: None,
        }),
        Panel::Lines(LinePanel {
            title: "Service file descriptors".into(),
            x_label: "minutes".into(),
            y_label: "open".into(),
            x_range: (0.0, t_max),
            y_range: (0.0, top(&mut fd.points.iter().map(|p| p.1))),
            series: vec![fd],
            legend: None,
        }),
        Panel::Lines(LinePanel {
            title: "Client reply latency per window (p50, p99)".into(),
            x_label: "minutes".into(),
            y_label: "ms".into(),
            x_range: (0.0, t_max),
            y_range: (0.0, top(&mut p99.points.iter().map(|p| p.1))),
            series: vec![p50, p99],
            legend: None,
        }),
    ];
    write_figure(&out.join("soak"), (1, 3), (1500, 420), &panels, true)
        .map_err(anyhow::Error::msg)?;
    Ok(())
}

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let minutes: f64 = args.next().map_or(Ok(30.0), |a| a.parse())?;
    let out = PathBuf::from(args.next().unwrap_or_else(|| "docs/reliability".into()));
    std::fs::create_dir_all(&out)?;
    let exe = std::env::current_exe()?;
    let nedrt = exe
        .parent()
        .and_then(Path::parent)
        .context("the example's folder")?
        .join("nedrt");
    let scratch = tempfile::tempdir()?;
    let socket = scratch.path().join("nedrt.sock");
    let shm = scratch.path().join("shm");
    std::fs::create_dir_all(&shm)?;
    let report_json = scratch.path().join("report.json");
    let mut service = Command::new(&nedrt)
        .args([
            "run",
            "--calib",
            "tests/data/small-panel.toml",
            "--backend",
            "cpu",
        ])
        .args(["--source", "socket", "--socket"])
        .arg(&socket)
        .arg("--shm-dir")
        .arg(&shm)
        .args(["--sink", "headless", "--report-json"])
        .arg(&report_json)
        .env("NEDRT_LOG", "nedrt=error")
        // wgpu's loader wants one; the headless sink needs no display.
        .env(
            "XDG_RUNTIME_DIR",
            std::env::var_os("XDG_RUNTIME_DIR").unwrap_or_else(|| "/tmp".into()),
        )
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .with_context(|| format!("starting {}", nedrt.display()))?;
    let pid = service.id();
    let started = Instant::now();
    while !socket.exists() {
        if started.elapsed() > Duration::from_secs(60) {
            bail!("the service did not listen within 60 s");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let stop = Arc::new(AtomicBool::new(false));
    let latencies = Arc::new(std::sync::Mutex::new(Vec::new()));
    let counts = Arc::new([AtomicU64::new(0), AtomicU64::new(0)]);
    let reconnects = Arc::new(AtomicU64::new(0));
    let streamer = {
        let (socket, shm, stop, lat, counts) = (
            socket.clone(),
            shm.clone(),
            stop.clone(),
            latencies.clone(),
            counts.clone(),
        );
        std::thread::spawn(move || stream(socket, shm, stop, lat, counts))
    };
    let churner = {
        let (socket, shm, stop, reconnects) = (
            socket.clone(),
            shm.clone(),
            stop.clone(),
            reconnects.clone(),
        );
        std::thread::spawn(move || churn(socket, shm, stop, reconnects))
    };
    let mut samples = Vec::new();
    let end = started + Duration::from_secs_f64(minutes * 60.0);
    while Instant::now() < end {
        std::thread::sleep(Duration::from_secs(SAMPLE_S).min(end - Instant::now()));
        if streamer.is_finished() || churner.is_finished() {
            break;
        }
        let mut window = std::mem::take(&mut *latencies.lock().unwrap_or_else(|p| p.into_inner()));
        window.sort_by(f64::total_cmp);
        let s = Sample {
            t_s: started.elapsed().as_secs_f64(),
            rss_kib: rss_kib(pid)?,
            fds: fds(pid)?,
            reply_p50_ms: quantile(&window, 0.5),
            reply_p99_ms: quantile(&window, 0.99),
            reply_max_ms: window.last().copied().unwrap_or(0.0),
            frames: counts[0].load(Ordering::Relaxed),
            bad_frames: counts[1].load(Ordering::Relaxed),
            reconnects: reconnects.load(Ordering::Relaxed),
        };
        println!(
            "{:>6.0} s  RSS {:>7} KiB  fds {:>3}  reply p50 {:.2} ms p99 {:.2} ms  frames {}",
            s.t_s, s.rss_kib, s.fds, s.reply_p50_ms, s.reply_p99_ms, s.frames
        );
        samples.push(s);
    }
    stop.store(true, Ordering::Relaxed);
    let stopped = Instant::now();
    Command::new("kill")
        .args(["-TERM", &pid.to_string()])
        .status()?;
    let status = service.wait()?;
    let stop_s = stopped.elapsed().as_secs_f64();
    for (name, t) in [("streaming", streamer), ("reconnecting", churner)] {
        match t.join() {
            Ok(Ok(())) => {}
            // The service going away under a client at the stop is expected.
            Ok(Err(e)) if stopped.elapsed() > Duration::ZERO && samples.len() > 1 => {
                eprintln!("{name} client ended: {e:#}")
            }
            Ok(Err(e)) => return Err(e.context(format!("the {name} client"))),
            Err(_) => bail!("the {name} client panicked"),
        }
    }
    if !status.success() {
        bail!("the service exited with {status}");
    }
    let report: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&report_json)?)?;
    let n = |k: &str| report[k].as_u64().unwrap_or(0);
    let rejected: u64 = report["rejected"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|p| p[1].as_u64())
        .sum();
    let accounted = n("presented")
        + rejected
        + n("dropped_queued")
        + n("dropped_at_present")
        + n("skipped")
        + n("in_flight_at_stop")
        + n("failed");
    // Flat after warm-up: the first fifth of the run is the warm-up.
    let settled = &samples[samples.len() / 5..];
    let range = |f: &dyn Fn(&Sample) -> u64| {
        let v: Vec<u64> = settled.iter().map(f).collect();
        (
            v.iter().copied().min().unwrap_or(0),
            v.iter().copied().max().unwrap_or(0),
        )
    };
    let (rss_lo, rss_hi) = range(&|s| s.rss_kib);
    let (fd_lo, fd_hi) = range(&|s| s.fds);
    let summary = serde_json::json!({
        "command": format!("cargo run --release --example soak -- {minutes}"),
        "minutes": minutes,
        "stop_s": stop_s,
        "report": report,
        "accounted": accounted,
        "after_warm_up": {
            "rss_kib_min": rss_lo, "rss_kib_max": rss_hi,
            "fds_min": fd_lo, "fds_max": fd_hi,
        },
        "samples": samples,
    });
    let mut f = Vec::new();
    writeln!(f, "{}", serde_json::to_string_pretty(&summary)?)?;
    nedrt_core::util::write_atomic(&out.join("soak.json"), &f)?;
    chart(&samples, &out)?;
    println!(
        "{} submitted, {accounted} accounted; after warm-up RSS {rss_lo}–{rss_hi} KiB, \
         descriptors {fd_lo}–{fd_hi}; SIGTERM took {stop_s:.2} s; wrote {}",
        n("submitted"),
        out.join("soak.{json,png,svg}").display()
    );
    if accounted != n("submitted") {
        bail!(
            "the books do not balance: {accounted} of {} accounted",
            n("submitted")
        );
    }
    Ok(())
}
