//! The recorder sink: every presented frame is written as an 8-bit RGB PNG
//! of the panel's code values, `frame-<id>.png` in a folder (a later frame
//! with an id already recorded in this run goes to `frame-<id>-<n>.png`,
//! never over the first), by a writer
//! thread (PNG encoding must not stall the present loop). Files are written
//! atomically; `finish` waits for every write, so a clean shutdown leaves
//! every presented frame on disk and never a half-written one.

use std::path::{Path, PathBuf};
use std::thread::JoinHandle;

use crossbeam_channel::{Sender, bounded};

use super::{DisplayFrame, PanelCodes, PresentError, Presented, Sink};
use nedrt_core::preprocess::HostTraffic;
use nedrt_core::util::write_atomic;

/// Frames that may wait for the writer before `present` waits for it.
const QUEUE: usize = 8;

const STAGE: &str = "recorder sink";

fn err(reason: impl std::fmt::Display) -> PresentError {
    PresentError::Write {
        stage: STAGE,
        reason: reason.to_string(),
    }
}

/// A PNG sequence writer.
#[derive(Debug)]
pub struct RecorderSink {
    dir: PathBuf,
    tx: Option<Sender<DisplayFrame>>,
    /// The frames written and, if it stopped early, why.
    writer: Option<JoinHandle<(u64, Result<(), String>)>>,
    /// Frames handed to the writer.
    sent: u64,
    /// Frames written, once the writer has ended.
    written: Option<u64>,
    /// The last present's read-back, for codes that were on a device.
    traffic: HostTraffic,
}

/// The file a frame is recorded in.
pub fn frame_path(dir: &Path, id: u64) -> PathBuf {
    dir.join(format!("frame-{id:08}.png"))
}

/// The file of the `n`-th frame (from 1) of a run that reused `id`.
pub fn repeated_frame_path(dir: &Path, id: u64, n: u64) -> PathBuf {
    dir.join(format!("frame-{id:08}-{n}.png"))
}

impl RecorderSink {
    /// Records into `dir` (created if missing).
    pub fn new(dir: &Path) -> Result<Self, PresentError> {
        std::fs::create_dir_all(dir).map_err(|e| {
            PresentError::open(STAGE, format!("cannot create {}: {e}", dir.display()))
        })?;
        let (tx, rx) = bounded::<DisplayFrame>(QUEUE);
        let out = dir.to_path_buf();
        let writer = std::thread::Builder::new()
            .name("recorder".into())
            .spawn(move || {
                let mut written = 0u64;
                // Ids are the clients' own; a repeated one gets a new name.
                let mut seen = std::collections::HashMap::<u64, u64>::new();
                let mut write = |frame: DisplayFrame| -> Result<(), String> {
                    let _span = tracing::trace_span!("record", id = frame.id).entered();
                    let rgb = super::rgb8_of_rgba8(&frame.rgba8);
                    let mut png = Vec::new();
                    image::ImageEncoder::write_image(
                        image::codecs::png::PngEncoder::new(&mut png),
                        &rgb,
                        frame.width as u32,
                        frame.height as u32,
                        image::ExtendedColorType::Rgb8,
                    )
                    .map_err(|e| format!("encoding frame {}: {e}", frame.id))?;
                    let repeats = seen.entry(frame.id).or_insert(0);
                    let path = match *repeats {
                        0 => frame_path(&out, frame.id),
                        n => {
                            if n == 1 {
                                tracing::warn!(
                                    "frame id {} presented again; recorded as {}",
                                    frame.id,
                                    repeated_frame_path(&out, frame.id, n).display()
                                );
                            }
                            repeated_frame_path(&out, frame.id, n)
                        }
                    };
                    *repeats += 1;
                    write_atomic(&path, &png)
                        .map_err(|e| format!("cannot write {}: {e}", path.display()))?;
                    written += 1;
                    Ok(())
                };
                let result = rx.into_iter().try_for_each(&mut write);
                (written, result)
            })
            .map_err(|e| PresentError::open(STAGE, format!("starting the writer: {e}")))?;
        Ok(Self {
            dir: dir.to_path_buf(),
            tx: Some(tx),
            writer: Some(writer),
            sent: 0,
            written: None,
            traffic: HostTraffic::default(),
        })
    }
}

impl Sink for RecorderSink {
    fn describe(&self) -> String {
        format!("recorder into {}", self.dir.display())
    }

    /// Codes on a device are read back first (one read-back, counted).
    fn present(&mut self, frame: PanelCodes<'_>) -> Result<Presented, PresentError> {
        let tx = self.tx.as_ref().ok_or_else(|| err("already finished"))?;
        self.traffic = HostTraffic::default();
        let (frame, traffic) = match frame {
            PanelCodes::Host(f) => (f.clone(), HostTraffic::default()),
            PanelCodes::Device(f) => (f.to_host()?, f.read_back_traffic()),
        };
        self.traffic = traffic;
        if tx.send(frame).is_err() {
            // The writer stopped: finish() reports why.
            return Err(self.finish().err().unwrap_or_else(|| err("writer stopped")));
        }
        self.sent += 1;
        Ok(Presented::Shown)
    }

    fn finish(&mut self) -> Result<(), PresentError> {
        self.tx = None;
        match self.writer.take() {
            Some(w) => {
                let (written, result) = w
                    .join()
                    .unwrap_or_else(|_| (0, Err("the writer thread panicked".into())));
                self.written = Some(written);
                tracing::debug!("recorder wrote {written} frames to {}", self.dir.display());
                result.map_err(|e| {
                    err(format!(
                        "{e} ({} of {} frames not recorded)",
                        self.sent - written,
                        self.sent
                    ))
                })
            }
            None => Ok(()),
        }
    }

    fn last_traffic(&self) -> HostTraffic {
        self.traffic
    }

    fn lost_frames(&self) -> u64 {
        self.written.map_or(0, |w| self.sent.saturating_sub(w))
    }
}

impl Drop for RecorderSink {
    fn drop(&mut self) {
        if let Err(e) = self.finish() {
            tracing::error!("{e}");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::deadline::{THREAD, within};

    #[test]
    fn every_presented_frame_is_on_disk_after_finish() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut sink = RecorderSink::new(&dir.path().join("rec")).expect("sink");
        let (w, h) = (5usize, 3usize);
        within(THREAD, "the recorder to write 20 frames", move || {
            for id in 0..20u64 {
                let rgba8 = (0..4 * w * h).map(|i| (i as u64 * 13 + id) as u8).collect();
                let frame = DisplayFrame {
                    id,
                    width: w,
                    height: h,
                    rgba8,
                };
                sink.present(PanelCodes::Host(&frame)).expect("present");
            }
            sink.finish().expect("finish");
        });
        for id in 0..20u64 {
            let img = image::open(frame_path(&dir.path().join("rec"), id))
                .expect("png")
                .to_rgb8();
            let want: Vec<u8> = (0..4 * w * h)
                .filter(|i| i % 4 != 3)
                .map(|i| (i as u64 * 13 + id) as u8)
                .collect();
            assert_eq!(img.into_raw(), want, "frame {id}");
        }
    }

    #[test]
    fn a_repeated_frame_id_is_recorded_beside_the_first_not_over_it() {
        let dir = tempfile::tempdir().expect("tempdir");
        let rec = dir.path().join("rec");
        let mut sink = RecorderSink::new(&rec).expect("sink");
        within(THREAD, "the recorder to write 3 frames", move || {
            for (id, level) in [(7u64, 10u8), (7, 20), (7, 30)] {
                let frame = DisplayFrame {
                    id,
                    width: 1,
                    height: 1,
                    rgba8: vec![level, level, level, 255],
                };
                sink.present(PanelCodes::Host(&frame)).expect("present");
            }
            sink.finish().expect("finish");
        });
        let level = |p: PathBuf| image::open(p).expect("png").to_rgb8().into_raw()[0];
        assert_eq!(level(frame_path(&rec, 7)), 10);
        assert_eq!(level(repeated_frame_path(&rec, 7, 1)), 20);
        assert_eq!(level(repeated_frame_path(&rec, 7, 2)), 30);
    }

    #[test]
    fn an_unwritable_folder_is_an_error_naming_it() {
        let dir = tempfile::tempdir().expect("tempdir");
        let file = dir.path().join("file");
        std::fs::write(&file, b"x").expect("write");
        let e = RecorderSink::new(&file.join("sub")).unwrap_err();
        assert!(e.to_string().contains("file"), "{e}");
    }

    mod needs_gpu {
        use super::*;
        use crate::present::DeviceDisplayFrame;
        use crate::present::encode_gpu::row_texels;
        use wgpu::util::DeviceExt;

        #[test]
        #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
        fn codes_on_a_device_are_recorded_as_the_same_codes_from_the_host() {
            let (device, queue) = nedrt_gpu::test_device(false);
            // 37 wide: rows padded to the 256-byte pitch, which must not leak.
            let (w, h) = (37usize, 5usize);
            let pitch = row_texels(w as u32) as usize;
            assert!(pitch > w);
            let code = |x: usize, y: usize, c: usize| ((x * 7 + y * 31 + c * 90) % 256) as u8;
            let mut padded = vec![0xEEu8; 4 * pitch * h];
            let mut packed = Vec::with_capacity(4 * w * h);
            for y in 0..h {
                for x in 0..w {
                    let px = [code(x, y, 0), code(x, y, 1), code(x, y, 2), 255];
                    padded[4 * (y * pitch + x)..][..4].copy_from_slice(&px);
                    packed.extend_from_slice(&px);
                }
            }
            let codes = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("test codes"),
                contents: &padded,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            });
            let on_device = DeviceDisplayFrame {
                id: 3,
                width: w,
                height: h,
                codes: std::sync::Arc::new(codes),
                row_texels: pitch as u32,
                device,
                queue,
            };
            let on_host = DisplayFrame {
                id: 4,
                width: w,
                height: h,
                rgba8: packed,
            };
            let dir = tempfile::tempdir().expect("tempdir");
            let mut sink = RecorderSink::new(dir.path()).expect("sink");
            let host_codes = on_host.rgba8.clone();
            within(THREAD, "the recorder to write 2 frames", move || {
                sink.present(PanelCodes::Device(&on_device))
                    .expect("device codes");
                assert_eq!(sink.last_traffic().read_backs, 1);
                sink.present(PanelCodes::Host(&on_host))
                    .expect("host codes");
                assert_eq!(sink.last_traffic(), HostTraffic::default());
                sink.finish().expect("finish");
            });
            let png = |id| {
                image::open(frame_path(dir.path(), id))
                    .expect("png")
                    .to_rgb8()
                    .into_raw()
            };
            assert_eq!(png(3), png(4));
            assert_eq!(png(4), crate::present::rgb8_of_rgba8(&host_codes));
        }
    }
}
