"""Independent golden for a defocused PSF, computed once with hcipy (PyPI),
for the Rust optics test `optics::golden` (tests/golden/hcipy_defocus.json).

    .venv/bin/pip install hcipy==0.7.1 numpy
    .venv/bin/python tools/golden/make_hcipy_golden.py

Two PSFs on the retinal grid (cells of Δθ = p/(2 z_d), each integrated with
m×m sub-samples) for λ = 530 nm and the target-blur defocus Ψ = 74 rad:
- "hcipy_aperture": hcipy's own circular aperture (area fraction by 16×
  supersampling) and hcipy's Fraunhofer propagator: independent of nedrt in
  aperture sampling, propagation and normalisation;
- "nedrt_pupil": hcipy's propagator applied to nedrt's pupil samples (linear
  edge ramp), so that only the propagation and normalisation are compared.
Cells are normalised by the pupil's total power (energy through the aperture).
"""
import json
from pathlib import Path

import hcipy
import numpy as np

OUT = Path(__file__).resolve().parents[2] / "tests" / "golden" / "hcipy_defocus.json"

R = 5e-3                      # aperture radius (m), calib/default.toml
PITCH = 8.7e-6                # panel pitch (m)
ZD = 28.57e-3                 # lens-to-panel distance (m)
DTHETA = PITCH / (2 * ZD)     # retinal cell (rad)
WAVELENGTH = 530e-9
PSI = 74.0                    # defocus coefficient (rad), the target blur
SAMPLES_ACROSS = 512          # pupil samples across the diameter
WINDOW = 61                   # cells
SUB = 4                       # sub-samples per cell axis


def cells_from(pupil_field, pupil_grid):
    n = WINDOW * SUB
    focal_grid = hcipy.make_uniform_grid([n, n], [n * DTHETA / SUB] * 2)  # angles (f = 1)
    prop = hcipy.FraunhoferPropagator(pupil_grid, focal_grid, focal_length=1)
    wf = hcipy.Wavefront(pupil_field, WAVELENGTH)
    img = prop.forward(wf)
    total = wf.total_power
    # hcipy's power is per sample (weights included): total_power = Σ power.
    power = np.asarray(img.power).reshape(n, n) / total
    return power.reshape(WINDOW, SUB, WINDOW, SUB).sum(axis=(1, 3))


def main():
    step = 2 * R / SAMPLES_ACROSS
    # nedrt's grid: N = ceil(2r/Δs) + 2 samples, s_n = (n − (N−1)/2)·Δs.
    n = int(np.ceil(2 * R / step)) + 2
    grid = hcipy.make_uniform_grid([n, n], [n * step, n * step])
    x, y = grid.x, grid.y
    rho2 = (x ** 2 + y ** 2) / R ** 2
    defocus = np.exp(1j * PSI * rho2)

    aperture = hcipy.evaluate_supersampled(hcipy.make_circular_aperture(2 * R), grid, 16)
    own = cells_from(hcipy.Field(aperture * defocus, grid), grid)

    ramp = np.clip((R - np.sqrt(x ** 2 + y ** 2)) / step + 0.5, 0, 1)
    ours = cells_from(hcipy.Field(ramp * defocus, grid), grid)

    OUT.write_text(json.dumps({
        "generator": f"hcipy {hcipy.__version__}, numpy {np.__version__}",
        "script": "tools/golden/make_hcipy_golden.py",
        "aperture_radius_m": R, "wavelength_m": WAVELENGTH, "psi_rad": PSI,
        "pupil_step_m": step, "pupil_samples": n, "cell_rad": DTHETA,
        "window": WINDOW, "sub_samples": SUB,
        "hcipy_aperture": own.ravel().tolist(),
        "nedrt_pupil": ours.ravel().tolist(),
    }))
    print("wrote", OUT, "window energy", own.sum(), ours.sum(), "peak", own.max())


if __name__ == "__main__":
    main()
