//! The workgroup-memory kernels' shapes tuned per adapter and frame size
//! (issue 56, item 4; docs/tuning.md). `nedrt bench tune` writes them into
//! the adapter's table under `tuning/` (the `[[fft]]` entries, read by
//! nedrt-infer, a layer above); the binary installs a [`TunedSource`] that
//! reads them, and every [`super::FftKernels`] made afterwards asks it once
//! for its device's adapter. A filter of a tuned size then runs the tuned
//! [`FusedVariant`]; any other size, or an adapter without a table, the
//! heuristics'. A shape moves butterflies between threads, never changes
//! their arithmetic: the output is the same bit for bit.

use std::sync::{Arc, Mutex, PoisonError};

use super::FusedVariant;

/// The tuned shapes of one adapter: ((width, height), variant).
pub type TunedSizes = Arc<Vec<((usize, usize), FusedVariant)>>;

/// Gives the tuned shapes for an adapter (none: the heuristics').
pub type TunedSource = Box<dyn Fn(&wgpu::AdapterInfo) -> TunedSizes + Send + Sync>;

struct Installed {
    source: TunedSource,
    /// Each adapter's answer, asked once: by (name, driver info, vendor,
    /// device, backend).
    asked: Vec<(AdapterId, TunedSizes)>,
}

type AdapterId = (String, String, u32, u32, wgpu::Backend);

static INSTALLED: Mutex<Option<Installed>> = Mutex::new(None);

/// Installs `source` for the kernels made from now on (replacing any
/// earlier one and forgetting its answers).
pub fn install(source: TunedSource) {
    *INSTALLED.lock().unwrap_or_else(PoisonError::into_inner) = Some(Installed {
        source,
        asked: Vec::new(),
    });
}

/// The tuned shapes for `info`'s adapter (empty without a source).
pub(super) fn for_adapter(info: &wgpu::AdapterInfo) -> TunedSizes {
    let mut installed = INSTALLED.lock().unwrap_or_else(PoisonError::into_inner);
    let Some(installed) = installed.as_mut() else {
        return TunedSizes::default();
    };
    let id = (
        info.name.clone(),
        info.driver_info.clone(),
        info.vendor,
        info.device,
        info.backend,
    );
    if let Some((_, sizes)) = installed.asked.iter().find(|(a, _)| *a == id) {
        return sizes.clone();
    }
    let sizes = (installed.source)(info);
    installed.asked.push((id, sizes.clone()));
    sizes
}
