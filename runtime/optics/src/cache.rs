//! On-disk PSF cache. A request's PSFs depend only on the calibration's
//! optics, the DOE's content, the propagator and the request itself; they
//! are stored under a key hashing all four (and this code's model version),
//! so a second run
//! loads instead of recomputing. A damaged or stale entry is recomputed, never trusted.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use safetensors::{Dtype, SafeTensors};

use super::psf::{Psf, PsfRequest, PsfSet, SamplingReport, propagator_for};
use super::{OpticsError, compute_psfs};
use nedrt_core::calib::Calibration;

/// Bump when the PSF model changes in a way that changes results
/// (3: the radial path for the lens alone and radial DOE profiles).
pub const MODEL_VERSION: &str = "nedrt-psf/3";

/// Where PSFs are cached; `None` disables caching.
#[derive(Debug, Clone, Default)]
pub struct PsfCache {
    pub dir: Option<PathBuf>,
    /// Most bytes of entries the folder keeps: past it, the entries used
    /// longest ago are removed after a new one is written (`None`: no
    /// bound).
    pub max_bytes: Option<u64>,
}

/// The bound of a cache made by [`PsfCache::at`]: a few of the largest
/// entries (a DOE's PSFs at every depth of a study reach 1.5 GB).
pub const DEFAULT_MAX_BYTES: u64 = 8 << 30;

impl PsfCache {
    /// A cache in `dir` (the binary chooses the folder: docs/README's
    /// `NEDRT_CACHE_DIR` rule), bounded by [`DEFAULT_MAX_BYTES`]; `None`
    /// disables caching.
    pub fn at(dir: Option<PathBuf>) -> Self {
        Self {
            dir,
            max_bytes: Some(DEFAULT_MAX_BYTES),
        }
    }

    /// The same cache with another bound (`None`: no bound).
    pub fn with_max_bytes(mut self, max_bytes: Option<u64>) -> Self {
        self.max_bytes = max_bytes;
        self
    }

    pub fn disabled() -> Self {
        Self {
            dir: None,
            max_bytes: None,
        }
    }

    /// Cache key of a request.
    pub fn key(calib: &Calibration, request: &PsfRequest) -> String {
        let mut h = blake3::Hasher::new();
        h.update(MODEL_VERSION.as_bytes());
        h.update(calib.optics_fingerprint().as_bytes());
        h.update(
            request
                .doe
                .map_or_else(|| "lens".to_string(), |d| d.content_hash())
                .as_bytes(),
        );
        h.update(propagator_for(calib, request.doe).to_string().as_bytes());
        for s in &request.specs {
            h.update(&(s.channel as u64).to_le_bytes());
            h.update(&s.psi_rad.to_le_bytes());
        }
        h.finalize().to_hex()[..32].to_string()
    }

    fn path(&self, key: &str) -> Option<PathBuf> {
        self.dir
            .as_ref()
            .map(|d| d.join(format!("psf-{key}.safetensors")))
    }

    /// Loads the request's PSFs from the cache or computes (and stores) them.
    pub fn get_or_compute(
        &self,
        calib: &Calibration,
        request: &PsfRequest,
        tick: &(dyn Fn() + Sync),
    ) -> Result<PsfSet, OpticsError> {
        let key = Self::key(calib, request);
        if let Some(path) = self.path(&key).filter(|p| p.exists()) {
            match read(&path, request.specs.len()) {
                Ok(mut set) => {
                    // Used now: the bound removes the entries used longest ago.
                    touch(&path);
                    set.report.from_cache = true;
                    tracing::debug!("PSFs from cache {}", path.display());
                    return Ok(set);
                }
                Err(e) => tracing::warn!(
                    "{}: ignoring damaged PSF cache entry ({e}); recomputing",
                    path.display()
                ),
            }
        }
        let set = compute_psfs(calib, request, tick)?;
        if let Some(path) = self.path(&key) {
            match write(&path, &set) {
                Err(e) => tracing::warn!(
                    "{}: cannot write PSF cache ({e}); continuing without it",
                    path.display()
                ),
                Ok(()) => {
                    if let (Some(dir), Some(max)) = (&self.dir, self.max_bytes) {
                        evict(dir, max, &path);
                    }
                }
            }
        }
        Ok(set)
    }
}

/// Marks a cache entry as used now (its modification time).
fn touch(path: &Path) {
    if let Ok(f) = std::fs::File::options().append(true).open(path) {
        let _ = f.set_modified(std::time::SystemTime::now());
    }
}

/// Removes the PSF entries of `dir` used longest ago until the rest take
/// at most `max_bytes`, never `keep` (the entry just written). Returns the
/// entries removed.
fn evict(dir: &Path, max_bytes: u64, keep: &Path) -> Vec<PathBuf> {
    let Ok(read) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut entries: Vec<(std::time::SystemTime, u64, PathBuf)> = read
        .filter_map(Result::ok)
        .filter(|e| {
            let name = e.file_name();
            let name = name.to_string_lossy();
            name.starts_with("psf-") && name.ends_with(".safetensors")
        })
        .filter_map(|e| {
            let meta = e.metadata().ok()?;
            Some((meta.modified().ok()?, meta.len(), e.path()))
        })
        .collect();
    let mut total: u64 = entries.iter().map(|(_, len, _)| len).sum();
    entries.sort();
    let mut removed = Vec::new();
    for (_, len, path) in entries {
        if total <= max_bytes {
            break;
        }
        if path == keep {
            continue;
        }
        match std::fs::remove_file(&path) {
            Ok(()) => {
                tracing::info!(
                    "{}: removed from the PSF cache (over its {} MB bound)",
                    path.display(),
                    max_bytes >> 20
                );
                total -= len;
                removed.push(path);
            }
            Err(e) => tracing::warn!("{}: cannot remove ({e})", path.display()),
        }
    }
    removed
}

fn write(path: &Path, set: &PsfSet) -> Result<(), String> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|e| e.to_string())?;
    }
    let w = set.psfs.first().map_or(0, |p| p.window);
    // f32 keeps 7 significant digits, far below every tolerance that uses them.
    let cells: Vec<u8> = set
        .psfs
        .iter()
        .flat_map(|p| p.cells.iter().flat_map(|v| (*v as f32).to_le_bytes()))
        .collect();
    let veil: Vec<u8> = set.psfs.iter().flat_map(|p| p.veil.to_le_bytes()).collect();
    let n = set.psfs.len();
    let views = [
        (
            "cells",
            safetensors::tensor::TensorView::new(Dtype::F32, vec![n, w, w], &cells),
        ),
        (
            "veil",
            safetensors::tensor::TensorView::new(Dtype::F64, vec![n], &veil),
        ),
    ];
    let mut tensors = Vec::new();
    for (name, v) in views {
        tensors.push((name, v.map_err(|e| e.to_string())?));
    }
    let report = serde_json::to_string(&set.report).map_err(|e| e.to_string())?;
    let meta = HashMap::from([("report".to_string(), report)]);
    let bytes = safetensors::serialize(tensors, Some(meta)).map_err(|e| e.to_string())?;
    nedrt_core::util::write_atomic(path, &bytes).map_err(|e| e.to_string())
}

fn read(path: &Path, expected: usize) -> Result<PsfSet, String> {
    let bytes = std::fs::read(path).map_err(|e| e.to_string())?;
    let (_, header) = SafeTensors::read_metadata(&bytes).map_err(|e| e.to_string())?;
    let report: SamplingReport = serde_json::from_str(
        header
            .metadata()
            .as_ref()
            .and_then(|m| m.get("report"))
            .ok_or("no report")?,
    )
    .map_err(|e| e.to_string())?;
    let t = SafeTensors::deserialize(&bytes).map_err(|e| e.to_string())?;
    let cells = t.tensor("cells").map_err(|e| e.to_string())?;
    let shape = cells.shape().to_vec();
    if cells.dtype() != Dtype::F32
        || shape.len() != 3
        || shape[0] != expected
        || shape[1] != shape[2]
    {
        return Err(format!("unexpected cells {:?} {shape:?}", cells.dtype()));
    }
    let f64s = |name: &str| -> Result<Vec<f64>, String> {
        let v = t.tensor(name).map_err(|e| e.to_string())?;
        if v.dtype() != Dtype::F64 || v.shape() != [expected] {
            return Err(format!("unexpected {name}"));
        }
        Ok(v.data()
            .chunks_exact(8)
            .map(|b| f64::from_le_bytes(b.try_into().unwrap_or([0; 8])))
            .collect())
    };
    let veil = f64s("veil")?;
    let w = shape[1];
    let values: Vec<f64> = cells
        .data()
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes(b.try_into().unwrap_or([0; 4])) as f64)
        .collect();
    if values.iter().any(|v| !v.is_finite()) || veil.iter().any(|v| !v.is_finite()) {
        return Err("non-finite values".into());
    }
    let psfs = values
        .chunks_exact(w * w)
        .zip(&veil)
        .map(|(c, v)| Psf {
            window: w,
            cells: c.to_vec(),
            veil: *v,
        })
        .collect();
    Ok(PsfSet { psfs, report })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::PsfSpec;
    use std::sync::atomic::{AtomicUsize, Ordering};

    #[test]
    fn second_run_loads_and_damage_is_recomputed() {
        let c = Calibration::default_embedded().expect("calib");
        let dir = tempfile::tempdir().expect("tmp");
        let cache = PsfCache::at(Some(dir.path().to_path_buf()));
        let req = PsfRequest {
            specs: vec![PsfSpec {
                channel: 1,
                psi_rad: 20.0,
            }],
            doe: None,
        };
        let ticks = AtomicUsize::new(0);
        let tick = || {
            ticks.fetch_add(1, Ordering::Relaxed);
        };
        let first = cache.get_or_compute(&c, &req, &tick).expect("compute");
        assert_eq!(ticks.load(Ordering::Relaxed), 1);
        let second = cache.get_or_compute(&c, &req, &tick).expect("load");
        assert_eq!(ticks.load(Ordering::Relaxed), 1, "no recomputation");
        assert!(second.report.from_cache);
        for (a, b) in first.psfs[0].cells.iter().zip(&second.psfs[0].cells) {
            assert!((a - b).abs() <= 1e-7 * a.abs().max(1e-30));
        }
        // Truncate the entry: it is recomputed, with a warning, not trusted.
        let path = cache.path(&PsfCache::key(&c, &req)).expect("path");
        let bytes = std::fs::read(&path).expect("read");
        std::fs::write(&path, &bytes[..bytes.len() / 2]).expect("truncate");
        cache.get_or_compute(&c, &req, &tick).expect("recompute");
        assert_eq!(ticks.load(Ordering::Relaxed), 2);
    }

    #[test]
    fn key_depends_on_request_calibration_and_doe() {
        let c = Calibration::default_embedded().expect("calib");
        let a = PsfRequest {
            specs: vec![PsfSpec {
                channel: 1,
                psi_rad: 20.0,
            }],
            doe: None,
        };
        let b = PsfRequest {
            specs: vec![PsfSpec {
                channel: 1,
                psi_rad: 20.5,
            }],
            doe: None,
        };
        let doe = crate::HeightMap::three_lens_init(&c, 100e-6);
        let d = PsfRequest {
            specs: a.specs.clone(),
            doe: Some(&doe),
        };
        let mut c2 = c.clone();
        c2.aperture_radius_m *= 0.9;
        let mut two_d = c.clone();
        two_d.simulation.propagator = nedrt_core::calib::PropagatorSetting::TwoD;
        let radial = crate::HeightMap::three_lens_radial(&c, 100e-6);
        let r = PsfRequest {
            specs: a.specs.clone(),
            doe: Some(&radial),
        };
        let keys = [
            PsfCache::key(&c, &a),
            PsfCache::key(&c, &b),
            PsfCache::key(&c, &d),
            PsfCache::key(&c2, &a),
            PsfCache::key(&two_d, &a),
            PsfCache::key(&c, &r),
        ];
        for i in 0..keys.len() {
            for j in i + 1..keys.len() {
                assert_ne!(keys[i], keys[j]);
            }
        }
    }

    #[test]
    fn the_bound_removes_the_entries_used_longest_ago_but_never_the_new_one() {
        let dir = tempfile::tempdir().expect("tmp");
        let at = |name: &str, bytes: usize, age_s: u64| {
            let p = dir.path().join(name);
            std::fs::write(&p, vec![0u8; bytes]).expect("write");
            let when = std::time::SystemTime::now() - std::time::Duration::from_secs(age_s);
            std::fs::File::options()
                .append(true)
                .open(&p)
                .expect("open")
                .set_modified(when)
                .expect("mtime");
            p
        };
        let oldest = at("psf-a.safetensors", 400, 300);
        let older = at("psf-b.safetensors", 400, 200);
        let recent = at("psf-c.safetensors", 400, 100);
        let other = at("notes.txt", 4000, 1000);
        let new = at("psf-d.safetensors", 400, 50);
        // 1600 bytes of entries, a bound of 900: the two used longest ago go.
        assert_eq!(evict(dir.path(), 900, &new), [oldest.clone(), older]);
        assert!(recent.exists() && new.exists() && other.exists());
        // Reading an entry marks it used: it outlives an older one.
        touch(&recent);
        let newer = at("psf-e.safetensors", 400, 0);
        assert_eq!(evict(dir.path(), 900, &newer), [new]);
        assert!(recent.exists());
        // A new entry larger than the bound stays (it is being used).
        let big = at("psf-f.safetensors", 2000, 0);
        let removed = evict(dir.path(), 900, &big);
        assert!(big.exists() && !removed.contains(&big), "{removed:?}");
        assert!(!oldest.exists());
    }
}
