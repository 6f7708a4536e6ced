"""Keys cubic convolution (a = −½, as nedrt's runtime/optics/src/doe.rs):
the kernel itself, and its taps and interpolation on a radial profile with
samples at (n + ½)·pitch (docs/doe-format.md).

A leaf of the package: numpy only, nothing from nedrt_train, so the
exporter (`export.resample`, the fabrication file) and the radial optics
(`radial.RadialPsfModel`, which sees the element that is made) share one
interpolation without importing each other."""
import numpy as np


def keys_weight(x: np.ndarray) -> np.ndarray:
    a = -0.5
    x = np.abs(x)
    return np.where(x <= 1, ((a + 2) * x - (a + 3)) * x * x + 1,
                    np.where(x < 2, ((a * x - 5 * a) * x + 8 * a) * x - 4 * a, 0.0))


def keys_taps(samples: int, pitch_m: float, rho_m: np.ndarray):
    """The four (index, weight) Keys taps (a = −½) of a radial profile with
    samples at (n + ½)·pitch, at radii `rho_m`: the profile's even extension
    about the axis (sample −1−k mirrors sample k), the last sample repeated
    past the end."""
    u = np.asarray(rho_m, dtype=np.float64) / pitch_m - 0.5
    base = np.floor(u)
    f = u - base
    idx, w = [], []
    for k, wk in [(-1, keys_weight(1 + f)), (0, keys_weight(f)), (1, keys_weight(1 - f)), (2, keys_weight(2 - f))]:
        i = (base + k).astype(np.int64)
        idx.append(np.clip(np.where(i < 0, -1 - i, i), 0, samples - 1))
        w.append(wk)
    return np.stack(idx, axis=-1), np.stack(w, axis=-1)


def keys_profile(height: np.ndarray, pitch_m: float, rho_m: np.ndarray, max_height_m: float) -> np.ndarray:
    """Heights of a radial profile (samples at (n + ½)·pitch) at radii `rho_m`
    by Keys cubic interpolation (a = −½, as nedrt), with the profile's even
    extension about the axis (sample −1−k mirrors sample k) and the last
    sample repeated past the end; clamped to [0, max] (a fabricated profile
    cannot leave its depth range)."""
    height = np.asarray(height, dtype=np.float64)
    idx, w = keys_taps(len(height), pitch_m, rho_m)
    return np.clip((height[idx] * w).sum(-1), 0.0, max_height_m)
