//! The viewer's window: input moves the accommodation, a worker thread
//! renders the picture the newest request asks for, and the window shows
//! the newest picture. At most one request waits ([`Latest`]), so turning
//! the wheel fast never queues work: the worker skips to where the eye
//! is now.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::sync::{Condvar, Mutex};
use std::time::{Duration, Instant};

use nedrt_service::present::window::{KeyName, WindowInput, WindowOptions, WindowSink};
use nedrt_service::present::{DisplayFrame, PanelCodes, Sink, rgb8_of_rgba8};

use super::compose::{Layout, Picture};
use super::scene::{FocusScene, Shown};
use super::{ViewOptions, picture_at, save_picture};
use crate::AppError;

/// What the worker is asked to draw.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Request {
    pub depth: usize,
    pub shown: Shown,
}

/// A slot holding the newest request only.
#[derive(Debug, Default)]
pub struct Latest {
    slot: Mutex<(Option<Request>, bool)>,
    ready: Condvar,
}

impl Latest {
    fn lock(&self) -> std::sync::MutexGuard<'_, (Option<Request>, bool)> {
        self.slot.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Replaces whatever request is waiting.
    pub fn put(&self, request: Request) {
        self.lock().0 = Some(request);
        self.ready.notify_one();
    }

    /// Waits for a request; `None` once closed.
    pub fn take(&self) -> Option<Request> {
        let mut slot = self.lock();
        loop {
            if slot.1 {
                return None;
            }
            if let Some(r) = slot.0.take() {
                return Some(r);
            }
            slot = self.ready.wait(slot).unwrap_or_else(|e| e.into_inner());
        }
    }

    pub fn close(&self) {
        self.lock().1 = true;
        self.ready.notify_all();
    }
}

/// The viewer's state, changed only by input and the sweep's clock (tested
/// without a window).
#[derive(Debug, Clone, PartialEq)]
pub struct ViewState {
    pub depth: usize,
    pub shown: Shown,
    pub sweeping: bool,
    pub quit: bool,
    /// A screenshot was asked for and not yet taken.
    pub screenshot: bool,
    depths_d: Vec<f64>,
    /// Grid steps of PageUp/PageDown (0.5 D).
    big_step: usize,
    sweep_up: bool,
    dragging: bool,
    cursor: (f64, f64),
    wheel: f64,
}

impl ViewState {
    pub fn new(depth: usize, shown: Shown, depths_d: &[f64]) -> Self {
        let step = if depths_d.len() > 1 {
            depths_d[1] - depths_d[0]
        } else {
            0.5
        };
        Self {
            depth,
            shown,
            sweeping: false,
            quit: false,
            screenshot: false,
            depths_d: depths_d.to_vec(),
            big_step: ((0.5 / step).round() as usize).max(1),
            sweep_up: true,
            dragging: false,
            cursor: (0.0, 0.0),
            wheel: 0.0,
        }
    }

    pub fn request(&self) -> Request {
        Request {
            depth: self.depth,
            shown: self.shown,
        }
    }

    /// The grid's last index.
    fn last(&self) -> usize {
        self.depths_d.len().saturating_sub(1)
    }

    fn step(&mut self, by: isize) {
        let last = self.last() as isize;
        self.depth = (self.depth as isize + by).clamp(0, last) as usize;
    }

    /// One input; `scale` maps window pixels to picture pixels, `max_d` is
    /// the slider's far end.
    pub fn apply(&mut self, input: &WindowInput, layout: &Layout, scale: (f64, f64), max_d: f64) {
        let big = self.big_step as isize;
        match input {
            WindowInput::Key(k) => match k {
                KeyName::Left | KeyName::Down => self.step(-1),
                KeyName::Right | KeyName::Up => self.step(1),
                KeyName::PageDown => self.step(-big),
                KeyName::PageUp => self.step(big),
                KeyName::Home => self.depth = 0,
                KeyName::End => self.depth = self.last(),
                KeyName::Space => self.sweeping = !self.sweeping,
                KeyName::Escape | KeyName::Char('q') => self.quit = true,
                KeyName::Char('s') => self.shown = Shown::Sharp,
                KeyName::Char('t') => self.shown = Shown::Target,
                KeyName::Char('p') => self.shown = Shown::Perceived,
                KeyName::Char('c') | KeyName::Enter => self.screenshot = true,
                KeyName::Char(_) => {}
            },
            WindowInput::Wheel { lines } => {
                self.wheel += lines;
                let whole = self.wheel.trunc();
                self.wheel -= whole;
                self.step(whole as isize);
            }
            WindowInput::Cursor { x, y } => {
                self.cursor = (x * scale.0, y * scale.1);
                if self.dragging {
                    self.slide(layout, max_d);
                }
            }
            WindowInput::LeftButton { pressed: true } => {
                self.dragging = self.slide(layout, max_d);
            }
            WindowInput::LeftButton { pressed: false } => self.dragging = false,
        }
    }

    /// Moves to the slider's point under the cursor; false off the slider.
    fn slide(&mut self, layout: &Layout, max_d: f64) -> bool {
        match layout.accommodation_at(self.cursor.0, self.cursor.1, max_d) {
            Some(d) => {
                self.depth = super::scene::nearest_index(&self.depths_d, d);
                self.sweeping = false;
                true
            }
            None => self.dragging && self.sweeping,
        }
    }

    /// The sweep's next step: across the range and back.
    pub fn tick_sweep(&mut self) {
        if self.sweep_up && self.depth >= self.last() {
            self.sweep_up = false;
        } else if !self.sweep_up && self.depth == 0 {
            self.sweep_up = true;
        }
        self.step(if self.sweep_up { 1 } else { -1 });
    }
}

/// The window's size: the picture's, scaled down to fit `max`.
pub fn fitted_window(layout: &Layout, max: (u32, u32)) -> (u32, u32) {
    let (w, h) = (layout.width as f64, layout.height as f64);
    let s = (f64::from(max.0) / w).min(f64::from(max.1) / h).min(1.0);
    (
        ((w * s).round() as u32).max(1),
        ((h * s).round() as u32).max(1),
    )
}

/// `DIR/nedrt-view-<D>D-<n>.png` with the first `n` not taken, so an
/// earlier session's screenshots stay.
fn unused_screenshot_path(dir: &std::path::Path, accommodation_d: f64) -> PathBuf {
    (1..)
        .map(|n| dir.join(format!("nedrt-view-{accommodation_d:.2}D-{n}.png")))
        .find(|p| !p.exists())
        .unwrap_or_else(|| dir.join("nedrt-view.png"))
}

/// A rendered picture with what it shows and how long it took.
type Drawn = (Request, Picture, Duration);

/// Runs the window until it is closed or `q` is pressed; returns a summary.
pub fn interactive(
    scene: &FocusScene,
    opts: &ViewOptions,
    depth: usize,
) -> Result<String, AppError> {
    let layout = Layout::of(scene, true);
    let mut sink = WindowSink::open(
        layout.width as u32,
        layout.height as u32,
        WindowOptions {
            title: "nedrt view".into(),
            collect_inputs: true,
            no_display_hint: Some("--headless --screenshot FILE.png".into()),
            window_size: Some(fitted_window(&layout, opts.max_window)),
            ..opts.window.clone()
        },
    )?;
    tracing::info!("window: {}", sink.describe());
    let latest = Latest::default();
    let (layout, latest) = (&layout, &latest);
    std::thread::scope(|s| {
        let (tx, rx) = crossbeam_channel::unbounded::<Result<Drawn, AppError>>();
        let worker = s.spawn(move || {
            while let Some(req) = latest.take() {
                let start = Instant::now();
                let drawn = picture_at(scene, layout, req.depth, req.shown)
                    .map(|p| (req, p, start.elapsed()));
                if tx.send(drawn).is_err() {
                    break;
                }
            }
        });
        let result = ui_loop(scene, opts, layout, &mut sink, latest, &rx, depth);
        latest.close();
        if worker.join().is_err() {
            return Err(AppError::thread("the viewer's render thread", "panicked"));
        }
        result
    })
}

fn ui_loop(
    scene: &FocusScene,
    opts: &ViewOptions,
    layout: &Layout,
    sink: &mut WindowSink,
    latest: &Latest,
    rx: &crossbeam_channel::Receiver<Result<Drawn, AppError>>,
    depth: usize,
) -> Result<String, AppError> {
    let max_d = scene.slider_max_d();
    let mut state = ViewState::new(depth, opts.shown, &scene.depths_d);
    let mut requested = state.request();
    latest.put(requested);
    let mut shown: Option<(Request, DisplayFrame)> = None;
    let mut last_present = Instant::now();
    let mut last_sweep = Instant::now();
    let mut render_ms: Vec<f64> = Vec::new();
    let mut present_ms: Vec<f64> = Vec::new();
    let mut saved: Vec<PathBuf> = Vec::new();
    let opened = Instant::now();
    while sink.poll() {
        let (sw, sh) = sink.surface_size();
        let scale = (
            layout.width as f64 / f64::from(sw.max(1)),
            layout.height as f64 / f64::from(sh.max(1)),
        );
        for input in sink.take_inputs() {
            state.apply(&input, layout, scale, max_d);
        }
        if state.quit {
            break;
        }
        // A press before the first picture waits for it.
        if state.screenshot
            && let Some((req, frame)) = &shown
        {
            state.screenshot = false;
            let path = unused_screenshot_path(&opts.screenshot_dir, scene.depths_d[req.depth]);
            // A failed save is reported and the viewer goes on.
            let picture = Picture {
                width: frame.width,
                height: frame.height,
                rgb8: rgb8_of_rgba8(&frame.rgba8),
            };
            match save_picture(&picture, &path) {
                Ok(()) => {
                    tracing::info!("saved {}", path.display());
                    saved.push(path);
                }
                Err(e) => tracing::warn!("screenshot not saved: {e}"),
            }
        }
        let caught_up = shown.as_ref().is_some_and(|(r, _)| *r == requested);
        if state.sweeping && caught_up && last_sweep.elapsed() >= Duration::from_millis(60) {
            state.tick_sweep();
            last_sweep = Instant::now();
        }
        if state.request() != requested {
            requested = state.request();
            latest.put(requested);
        }
        let mut newest = None;
        loop {
            match rx.try_recv() {
                Ok(drawn) => newest = Some(drawn?),
                Err(crossbeam_channel::TryRecvError::Empty) => break,
                Err(crossbeam_channel::TryRecvError::Disconnected) => {
                    return Err(AppError::thread(
                        "the viewer's render thread",
                        "stopped (panicked)",
                    ));
                }
            }
        }
        if let Some((req, picture, took)) = newest {
            render_ms.push(took.as_secs_f64() * 1e3);
            let frame = DisplayFrame {
                id: render_ms.len() as u64,
                width: picture.width,
                height: picture.height,
                rgba8: picture.rgba8(),
            };
            let start = Instant::now();
            sink.present(PanelCodes::Host(&frame))?;
            present_ms.push(start.elapsed().as_secs_f64() * 1e3);
            last_present = Instant::now();
            shown = Some((req, frame));
        } else if last_present.elapsed() >= Duration::from_millis(500)
            && let Some((_, frame)) = &shown
        {
            // Redrawn now and then: a window uncovered shows the picture again.
            sink.present(PanelCodes::Host(frame))?;
            last_present = Instant::now();
        }
        std::thread::sleep(Duration::from_millis(8));
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(0.0)
    };
    let mut t = String::new();
    let _ = writeln!(
        t,
        "closed after {:.1} s: {} pictures drawn, median {:.0} ms each to render ({} methods, \
         memo included) and {:.1} ms to present",
        opened.elapsed().as_secs_f64(),
        render_ms.len(),
        median(&mut render_ms),
        scene.methods.len(),
        median(&mut present_ms)
    );
    for p in &saved {
        let _ = writeln!(t, "saved {}", p.display());
    }
    Ok(t)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state() -> (ViewState, Layout) {
        let depths = crate::viewer::depth_grid(0.0, 3.0, 0.05).expect("grid");
        (
            ViewState::new(30, Shown::Perceived, &depths),
            Layout::new(3, 64, 64, true),
        )
    }

    #[test]
    fn keys_and_the_wheel_move_the_accommodation_within_the_range() {
        let (mut s, l) = state();
        let key = |s: &mut ViewState, k| s.apply(&WindowInput::Key(k), &l, (1.0, 1.0), 3.0);
        key(&mut s, KeyName::Right);
        assert_eq!(s.depth, 31);
        key(&mut s, KeyName::PageUp);
        assert_eq!(s.depth, 41, "PageUp is 0.5 D");
        key(&mut s, KeyName::End);
        key(&mut s, KeyName::Right);
        assert_eq!(s.depth, 60, "stops at 3 D");
        key(&mut s, KeyName::Home);
        key(&mut s, KeyName::Left);
        assert_eq!(s.depth, 0, "stops at 0 D");
        for _ in 0..3 {
            s.apply(&WindowInput::Wheel { lines: 0.5 }, &l, (1.0, 1.0), 3.0);
        }
        assert_eq!(s.depth, 1, "half lines add up");
        key(&mut s, KeyName::Char('t'));
        assert_eq!(s.shown, Shown::Target);
        key(&mut s, KeyName::Char('c'));
        assert!(s.screenshot);
        key(&mut s, KeyName::Escape);
        assert!(s.quit);
    }

    #[test]
    fn dragging_the_slider_follows_the_cursor() {
        let (mut s, l) = state();
        let (x0, x1, y) = l.track();
        let y = f64::from(y);
        // The window at half the picture's size: positions scale by 2.
        let scale = (2.0, 2.0);
        s.apply(
            &WindowInput::Cursor {
                x: x0 / 2.0,
                y: y / 2.0,
            },
            &l,
            scale,
            3.0,
        );
        s.apply(&WindowInput::LeftButton { pressed: true }, &l, scale, 3.0);
        assert_eq!(s.depth, 0);
        s.apply(
            &WindowInput::Cursor {
                x: (x0 + (x1 - x0) / 2.0) / 2.0,
                y: 0.0,
            },
            &l,
            scale,
            3.0,
        );
        assert_eq!(s.depth, 0, "off the band, the handle stays");
        s.apply(
            &WindowInput::Cursor {
                x: (x0 + (x1 - x0) / 2.0) / 2.0,
                y: y / 2.0,
            },
            &l,
            scale,
            3.0,
        );
        assert_eq!(s.depth, 30, "1.5 D");
        s.apply(&WindowInput::LeftButton { pressed: false }, &l, scale, 3.0);
        s.apply(&WindowInput::Cursor { x: x1, y: y / 2.0 }, &l, scale, 3.0);
        assert_eq!(s.depth, 30, "released: moving does nothing");
    }

    #[test]
    fn the_sweep_bounces_between_the_ends() {
        let depths = [0.0, 1.0, 2.0];
        let mut s = ViewState::new(1, Shown::Perceived, &depths);
        let seen: Vec<usize> = (0..6)
            .map(|_| {
                s.tick_sweep();
                s.depth
            })
            .collect();
        assert_eq!(seen, [2, 1, 0, 1, 2, 1]);
    }

    #[test]
    fn the_newest_request_replaces_a_waiting_one() {
        // `take` waits while nothing is there and the slot is open: a
        // regression there fails the test instead of hanging it.
        let latest = std::sync::Arc::new(Latest::default());
        for depth in 0..5 {
            latest.put(Request {
                depth,
                shown: Shown::Perceived,
            });
        }
        let waiting = latest.clone();
        let taken = crate::deadline::within(
            crate::deadline::THREAD,
            "take() to return the waiting request",
            move || waiting.take(),
        );
        assert_eq!(taken.map(|r| r.depth), Some(4));
        latest.close();
        let closed = crate::deadline::within(
            crate::deadline::THREAD,
            "take() to return None once closed",
            move || latest.take(),
        );
        assert_eq!(closed, None);
    }

    #[test]
    fn a_large_picture_fits_the_window() {
        let l = Layout::new(3, 1024, 1024, true);
        let (w, h) = fitted_window(&l, (1600, 1000));
        assert!(w <= 1600 && h <= 1000);
        let ratio = |a: f64, b: f64| a / b;
        assert!((ratio(w as f64, h as f64) - ratio(l.width as f64, l.height as f64)).abs() < 0.01);
        let small = Layout::new(1, 64, 64, true);
        assert_eq!(
            fitted_window(&small, (1600, 1000)),
            (small.width as u32, small.height as u32)
        );
    }
}
