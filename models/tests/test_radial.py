"""The radial (Hankel) optics model against closed forms (Airy pattern,
encircled energy, disk ∩ rectangle areas), against the 2-D model with
exact cells on the same element, its convergence in the annulus width, and
its gradients against finite differences."""
import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from nedrt_train import calib as calib_mod
from nedrt_train.keys import keys_profile
from nedrt_train.optics import PsfModel, grid, perceive
from nedrt_train.radial import (RadialPsfModel, annulus_cell_weights, disk_rect_area, octant_cells,
                                radial_nodes, three_lens_profile)

REPO = Path(__file__).resolve().parents[2]
CAL = calib_mod.load(REPO / "calib" / "default.toml")
SMALL = calib_mod.load(REPO / "tests" / "data" / "small-aperture.toml")


def j1(x):
    return torch.special.bessel_j1(torch.as_tensor(x, dtype=torch.float64))


def j0(x):
    return torch.special.bessel_j0(torch.as_tensor(x, dtype=torch.float64))


def test_disk_rect_area_against_a_fine_raster():
    rng = np.random.default_rng(4)
    n = 1200
    for _ in range(6):
        radius = rng.uniform(0.2, 1.5)
        x0, y0 = rng.uniform(-1.2, 1.0, 2)
        x1, y1 = x0 + rng.uniform(0.05, 1.0), y0 + rng.uniform(0.05, 1.0)
        xs = x0 + (np.arange(n) + 0.5) * (x1 - x0) / n
        ys = y0 + (np.arange(n) + 0.5) * (y1 - y0) / n
        inside = (xs[None, :] ** 2 + ys[:, None] ** 2 <= radius ** 2).mean() * (x1 - x0) * (y1 - y0)
        exact = disk_rect_area(np.array(radius), x0, x1, y0, y1)
        assert abs(exact - inside) < 2e-3 * (x1 - x0) * (y1 - y0)
    # Closed cases: the rectangle inside the disk, the disk inside the rectangle.
    assert disk_rect_area(np.array(10.0), -1, 2, -0.5, 0.5) == pytest.approx(3.0, abs=1e-12)
    assert disk_rect_area(np.array(1.0), -3, 3, -3, 3) == pytest.approx(math.pi, abs=1e-12)


def test_annulus_weights_partition_every_annulus_inside_the_window():
    window, cell = 9, 1.0
    index, weights, t = annulus_cell_weights(window, cell, 8)
    _, _, full = octant_cells(window)
    per_annulus = np.zeros(len(t))
    for c in full:  # every cell of the window through its octant representative
        np.add.at(per_annulus, index[c], weights[c])
    delta = cell / 8
    a = np.arange(len(t)) * delta
    inside = a + delta <= window / 2 * cell
    assert np.allclose(per_annulus[inside], math.pi * ((a + delta) ** 2 - a ** 2)[inside], rtol=1e-12, atol=1e-15)


def test_nodes_cover_the_aperture_area_exactly():
    rho, area = radial_nodes(5e-3, 6e-6)
    assert area.sum() == pytest.approx(math.pi * 25e-6, rel=1e-12)
    assert rho[0] == pytest.approx(3e-6) and (len(rho) - 1) * 6e-6 < 5e-3 <= len(rho) * 6e-6


def test_in_focus_field_is_the_airy_pattern_and_encloses_its_energy():
    # Fine annuli: the encircled energy is summed by the midpoint rule here.
    m = RadialPsfModel(CAL, CAL.doe_design_pitch_m, 15, annuli_per_cell=128, richardson=False)
    ch = 1
    lam, r = CAL.channels[ch].wavelength_m, CAL.aperture_radius_m
    p = m.density(ch, [0.0], with_doe=False)[0]
    x = 2 * math.pi * r * m.t / lam
    airy = math.pi * r ** 2 / lam ** 2 * (2 * j1(x) / x) ** 2
    assert (p - airy).abs().max() < 1e-6 * airy.max()
    # Encircled energy 1 − J0² − J1² at the edge of each cell ring.
    delta = m.t[1] - m.t[0]
    cumulative = torch.cumsum(p * 2 * math.pi * m.t * delta, 0)
    for k in [1, 3, 7]:
        i = int(round(float(k * CAL.retinal_step_rad / delta))) - 1
        xr = 2 * math.pi * r * (m.t[i] + delta / 2) / lam
        closed = 1 - j0(xr) ** 2 - j1(xr) ** 2
        assert abs(cumulative[i] - closed) < 3e-4, (k, float(cumulative[i]), float(closed))


def test_cells_converge_in_the_annulus_width():
    # The hardest case: the in-focus lens at full aperture (Airy core 0.42 cells).
    reference = RadialPsfModel(CAL, CAL.doe_design_pitch_m, 15, annuli_per_cell=256, richardson=False)
    default = RadialPsfModel(CAL, CAL.doe_design_pitch_m, 15)
    plain16 = RadialPsfModel(CAL, CAL.doe_design_pitch_m, 15, richardson=False)
    ch = 1
    psi = CAL.psi_rad(ch, CAL.vergence_d(ch))
    ref = reference.psf(ch, psi, with_doe=False)[0]
    err = (default.psf(ch, psi, with_doe=False)[0] - ref).abs().max() / ref.max()
    err16 = (plain16.psf(ch, psi, with_doe=False)[0] - ref).abs().max() / ref.max()
    assert err < 1e-3 < err16, (float(err), float(err16))


@pytest.mark.parametrize("ch", [0, 1, 2])
def test_radial_matches_the_2d_model_on_the_same_element(ch):
    # The three-lens DOE as a radial profile at 6 µm, carried to a 3 µm
    # pupil by the same Keys interpolation for both models (small aperture
    # so that the 2-D model stays quick).
    window, pitch = 31, 3e-6
    design_rho, _ = radial_nodes(SMALL.aperture_radius_m, 6e-6)
    profile = three_lens_profile(SMALL, design_rho).numpy()
    flat = PsfModel(SMALL, pitch, window)
    s = grid(SMALL, pitch).numpy()
    map_m = torch.tensor(keys_profile(profile, 6e-6, np.hypot(s[None, :], s[:, None]), SMALL.doe_max_height_m))
    radial = RadialPsfModel(SMALL, 6e-6, window, quadrature_pitch_m=pitch)
    for d in [0.0, 0.5, 1.5, 2.5, 3.0]:
        psi = SMALL.psi_rad(ch, d)
        for with_doe in [True, False]:
            a, va = flat.psf(ch, psi, with_doe, height_m=map_m)
            b, vb = radial.psf(ch, psi, with_doe, height_m=torch.tensor(profile))
            assert (a - b).abs().max() < 5e-3 * a.max(), (d, with_doe)
            assert abs(float(va - vb)) < 2e-3


def test_window_plus_veil_is_all_the_light_and_a_wide_window_holds_it():
    m = RadialPsfModel(SMALL, 6e-6, 61)
    for ch in range(3):
        cells, veil = m.psf(ch, SMALL.psi_rad(ch, 0.5), with_doe=False)
        assert float(cells.sum() + veil) == pytest.approx(1.0, abs=1e-12)
        assert 0 <= float(veil) < 0.01
        assert float(cells.min()) > -1e-6 * float(cells.max())


def test_keys_profile_reproduces_even_quadratics_through_the_axis():
    pitch = 6e-6
    rho, _ = radial_nodes(1e-3, pitch)
    f = lambda r: 1e-6 + 2.0 * r ** 2                           # noqa: E731 — even in ρ
    fine = np.linspace(0, 0.9e-3, 301)
    got = keys_profile(f(rho), pitch, fine, 1.0)
    assert np.abs(got - f(fine)).max() < 1e-15 + 1e-12 * f(fine).max()


def test_gradients_of_the_radial_optics_match_finite_differences():
    small = dataclasses.replace(CAL, aperture_radius_m=60e-6)
    m = RadialPsfModel(small, 10e-6, 5, quadrature_pitch_m=5e-6)
    x = torch.rand(1, 3, 6, 6, dtype=torch.float64)

    def perceived(logit):
        height = small.doe_max_height_m * torch.sigmoid(logit)
        psfs = [m.psf(ch, small.psi_rad(ch, 1.0), height_m=height) for ch in range(3)]
        return perceive(x, psfs)

    logit = m.doe.logit.detach().clone().requires_grad_(True)
    assert torch.autograd.gradcheck(perceived, (logit,), eps=1e-6, atol=1e-7, rtol=1e-4)


def test_a_window_the_pupil_pitch_cannot_resolve_is_refused():
    with pytest.raises(ValueError, match="cannot resolve"):
        RadialPsfModel(CAL, 60e-6, 301, quadrature_pitch_m=60e-6)


@pytest.mark.parametrize("eye", [[], ["--pupil-mm", "4", "--eye-lca", "on"]], ids=["paper", "4mm+lca"])
def test_trainer_psfs_agree_with_nedrt_for_the_same_doe(tmp_path, eye):
    # The same element, the three-lens profile at the 6 µm design pitch
    # carried to the 3 µm fabrication file by the export's Keys
    # interpolation, through nedrt's planner (its own finer pupil step and
    # window, cells integrated exactly) and through the trainer's model at a
    # fine (1.5 µm) quadrature: the system PSF's central cut of `nedrt psf`,
    # to 0.5 % of its peak (acceptance line of issue 14). The training
    # default, 3 µm, is within 0.8 % (docs/training.md). Also through a
    # 4 mm eye pupil with the eye's LCA (docs/model.md §4a).
    import csv
    import subprocess
    from nedrt_train.export import save_doe
    exe = REPO / "target" / "release" / "nedrt"
    if not exe.exists():
        pytest.fail("target/release/nedrt is not built: scripts/test.sh builds it before pytest")
    cal = CAL
    if eye:
        cal = dataclasses.replace(CAL, eye_pupil_diameter_m=4e-3, eye_lca=True)
    model = RadialPsfModel(cal, cal.doe_design_pitch_m, 81, quadrature_pitch_m=1.5e-6)
    profile = three_lens_profile(CAL, model.design_rho_m).numpy()
    fab_rho, _ = radial_nodes(CAL.aperture_radius_m, CAL.doe_fabrication_pitch_m)
    fabricated = keys_profile(profile, CAL.doe_design_pitch_m, fab_rho, CAL.doe_max_height_m)
    doe = tmp_path / "three-lens-radial.safetensors"
    save_doe(doe, fabricated, CAL.doe_fabrication_pitch_m, CAL.doe_max_height_m, CAL.material_name,
             CAL.channels[CAL.design_channel].wavelength_m, "three-lens profile")
    out = subprocess.run([str(exe), "--doe", str(doe), "--cache-dir", str(tmp_path / "cache"), *eye, "psf",
                          "--out-dir", str(tmp_path), "--step", "1.0"], capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr
    rows = list(csv.DictReader(open(next(tmp_path.glob("*.csv")))))
    names = [c.name for c in CAL.channels]
    depths = sorted({float(r["accommodation_d"]) for r in rows})
    assert depths == [0.0, 1.0, 2.0, 3.0]
    cell_arcmin = math.degrees(CAL.retinal_step_rad) * 60
    for optics in ["lens + DOE", "lens only"]:
        for d in depths:
            for ch, name in enumerate(names):
                theirs = {round(float(r["angle_arcmin"]) / cell_arcmin * 2): float(r["value"]) for r in rows
                          if r["optics"] == optics and float(r["accommodation_d"]) == d and r["channel"] == name}
                cells, _ = model.psf(ch, cal.psi_rad(ch, d), with_doe=optics == "lens + DOE",
                                     height_m=torch.tensor(profile))
                w = cells.shape[0]
                sys_psf = torch.nn.functional.pad(cells, (0, 1, 0, 1)) / 4
                sys_psf = sys_psf + sys_psf.roll(1, 0) + sys_psf.roll(1, 1) + sys_psf.roll((1, 1), (0, 1))
                c = (w - 1) // 2
                cut = 0.5 * (sys_psf[c] + sys_psf[c + 1])
                # Half-cell angle units: x − (n − 1)/2 with n = w + 1.
                mine = {round(2 * (x - w / 2)): float(cut[x]) for x in range(w + 1)}
                peak = max(theirs.values())
                diff = max(abs(mine[k] - v) for k, v in theirs.items())
                assert diff < 5e-3 * peak, (optics, d, name, diff / peak)


def test_a_small_eye_pupil_in_focus_gives_its_own_airy_cells():
    # docs/model.md §4a: a 3 mm pupil at 0 mm relief, lens alone in focus:
    # each cell the Airy pattern of a 1.5 mm disk integrated over the cell.
    cal = dataclasses.replace(CAL, eye_pupil_diameter_m=3e-3, eye_relief_m=0.0)
    model = RadialPsfModel(cal, cal.doe_design_pitch_m, 21, quadrature_pitch_m=1.5e-6)
    assert model.stop_radius_m == [1.5e-3] * 3
    g = cal.design_channel
    cells, _ = model.psf(g, 0.0, with_doe=False)
    lam, a, dt = cal.channels[g].wavelength_m, 1.5e-3, cal.retinal_step_rad
    sub = 24
    off = ((np.arange(21 * sub) + 0.5) / sub - 10.5) * dt
    x = 2 * math.pi * a * np.hypot(off[None, :], off[:, None]) / lam
    airy = (2 * j1(torch.tensor(x)).numpy() / x) ** 2 * math.pi * a * a / lam ** 2 * (dt / sub) ** 2
    want = airy.reshape(21, sub, 21, sub).sum(axis=(1, 3))
    assert np.abs(cells.numpy() - want).max() < 2e-3 * want.max()


def test_the_eye_in_the_calibration_is_read_and_checked(tmp_path):
    text = (REPO / "calib" / "default.toml").read_text()
    p = tmp_path / "eye.toml"
    p.write_text(text.replace("[eye]\n", "[eye]\npupil_diameter_mm = 4.0\n").replace('lca = "off"', 'lca = "thibos1992"'))
    cal = calib_mod.load(p)
    # Thibos 1992 by hand at 600 / 530 / 450 nm relative to 530 nm.
    assert [round(cal.eye_lca_d(c), 5) for c in range(3)] == [0.36374, 0.0, -0.68004]
    assert abs(cal.psi_rad(2, cal.vergence_d(2) + cal.eye_lca_d(2))) < 1e-9
    assert cal.stop_radius_m(1) == pytest.approx(2e-3 / (1 + 15e-3 * cal.vergence_d(1)))
    # Only the radial model puts the pupil in the pupil: the 2-D one refuses.
    with pytest.raises(ValueError, match="paper's eye only"):
        PsfModel(cal, cal.doe_design_pitch_m, 9)
    for edit, field in [('field_deg = 0.0', 'field_deg = 10.0'), ('lca = "off"', 'lca = "maybe"')]:
        p.write_text(text.replace("[eye]\n", "[eye]\npupil_diameter_mm = 4.0\n").replace(*[edit, field]))
        with pytest.raises(ValueError, match="eye."):
            calib_mod.load(p)
