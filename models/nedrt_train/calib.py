"""The calibration (calib/*.toml) and the quantities derived from it,
docs/model.md §2–§5. Field names follow the TOML; values are SI.

The package never looks for the repository: every command takes the
calibration file as an argument (`--calib FILE`, by default
`calib/default.toml` under the current directory, see `resolve`), and the
functions receive the loaded `Calib` or the file's path."""
import dataclasses
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

from .paths import resolve_cli_path

#: Where a command looks for the calibration when `--calib` is not given,
#: relative to the current directory (the repository root, usually).
DEFAULT_RELATIVE = Path("calib") / "default.toml"


def thibos_refraction_d(wavelength_m: float) -> float:
    """Thibos et al. 1992: R(λ) = 1.68524 − 0.63346/(λ/µm − 0.21410) diopters."""
    return 1.68524 - 0.63346 / (wavelength_m * 1e6 - 0.21410)


@dataclass(frozen=True)
class Channel:
    name: str
    wavelength_m: float
    index: float


@dataclass(frozen=True)
class Calib:
    pixel_pitch_m: float
    lens_distance_m: float
    focal_length_spec_m: float
    index_at_spec: float
    aperture_radius_m: float
    channels: tuple
    design_channel: int
    doe_design_pitch_m: float
    doe_fabrication_pitch_m: float
    doe_max_height_m: float
    main_d: tuple
    intermediate_d: tuple
    target_blur_psi_rad: float
    range_d: tuple = (0.0, 3.0)
    wiener_average_step_d: float = 0.1
    material_name: str = "fused silica"
    # The eye (docs/model.md §4a): entrance-pupil diameter (None: the
    # eyepiece's aperture is the stop), relief from the lens plane, and
    # whether the eye has Thibos et al. 1992's chromatic aberration. The
    # trainer designs on axis (a field angle is refused at load).
    eye_pupil_diameter_m: float | None = None
    eye_relief_m: float = 15e-3
    eye_lca: bool = False

    def focal_length_m(self, ch: int) -> float:
        return self.focal_length_spec_m * (self.index_at_spec - 1) / (self.channels[ch].index - 1)

    def vergence_d(self, ch: int) -> float:
        return 1 / self.lens_distance_m - 1 / self.focal_length_m(ch)

    def eye_lca_d(self, ch: int) -> float:
        """The eye's chromatic difference of refraction at `ch` relative to
        the design channel (Thibos et al. 1992), 0 without eye LCA."""
        if not self.eye_lca:
            return 0.0
        return thibos_refraction_d(self.channels[ch].wavelength_m) - thibos_refraction_d(
            self.channels[self.design_channel].wavelength_m)

    def seen_vergence_d(self, ch: int) -> float:
        """The vergence at which the eye sees `ch` in focus: V_λ + ΔR_eye (§4a)."""
        return self.vergence_d(ch) + self.eye_lca_d(ch)

    def psi_rad(self, ch: int, accommodation_d: float) -> float:
        lam = self.channels[ch].wavelength_m
        return math.pi / lam * (self.seen_vergence_d(ch) - accommodation_d) * self.aperture_radius_m ** 2

    def stop_radius_m(self, ch: int, pupil_diameter_m: float | None = None) -> float:
        """The radius of the stop in the lens plane for `ch`: the eye's pupil
        (`pupil_diameter_m`, else the calibration's) projected along the
        image's rays, r_eye/(1 + e·V_λ), where it is inside the aperture;
        else the aperture's radius."""
        d = self.eye_pupil_diameter_m if pupil_diameter_m is None else pupil_diameter_m
        if d is None:
            return self.aperture_radius_m
        return min(self.aperture_radius_m, 0.5 * d / (1 + self.eye_relief_m * self.vergence_d(ch)))

    @property
    def retinal_step_rad(self) -> float:
        return self.pixel_pitch_m / (2 * self.lens_distance_m)

    @property
    def wave_height_m(self) -> float:
        c = self.channels[self.design_channel]
        return c.wavelength_m / (c.index - 1)

    def doe_phase_per_m(self, ch: int) -> float:
        c = self.channels[ch]
        return 2 * math.pi * (c.index - 1) / c.wavelength_m

    def is_main_depth(self, d: float) -> bool:
        return any(abs(d - m) < 1e-9 for m in self.main_d)

    @property
    def depths_d(self) -> list:
        return sorted(self.main_d + self.intermediate_d)


def resolve(arg=None, cwd=None) -> Path:
    """The calibration file a command line names: `arg`, or
    `calib/default.toml` under `cwd` (the current directory) when `arg` is
    None; absolute. Raises FileNotFoundError naming the path when it is not
    a file."""
    return resolve_cli_path(arg, DEFAULT_RELATIVE, cwd, folder=False, what="calibration file", flag="--calib FILE")


def load(path) -> Calib:
    """Reads a calibration; raises ValueError naming the file and field."""
    if path is None:
        raise ValueError("no calibration file given (pass --calib FILE)")
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text())
        channels = tuple(Channel(c["name"], c["wavelength_nm"] * 1e-9, c["index"]) for c in raw["channel"])
        names = [c.name for c in channels]
        cal = Calib(
            pixel_pitch_m=raw["panel"]["pixel_pitch_um"] * 1e-6,
            lens_distance_m=raw["panel"]["lens_distance_mm"] * 1e-3,
            focal_length_spec_m=raw["lens"]["focal_length_mm"] * 1e-3,
            index_at_spec=raw["material"]["index_at_spec"],
            aperture_radius_m=raw["lens"]["aperture_radius_mm"] * 1e-3,
            channels=channels,
            design_channel=names.index(raw["doe"]["design_channel"]),
            doe_design_pitch_m=raw["doe"]["design_pitch_um"] * 1e-6,
            doe_fabrication_pitch_m=raw["doe"]["fabrication_pitch_um"] * 1e-6,
            doe_max_height_m=raw["doe"]["max_height_um"] * 1e-6,
            main_d=tuple(raw["depths"]["main_d"]),
            intermediate_d=tuple(raw["depths"]["intermediate_d"]),
            target_blur_psi_rad=raw["target_blur"]["psi_rad"],
            range_d=tuple(raw["depths"]["range_d"]),
            wiener_average_step_d=raw["wiener"]["average_step_d"],
            material_name=raw["material"]["name"],
        )
    except (KeyError, ValueError, tomllib.TOMLDecodeError) as e:
        raise ValueError(f"{path}: invalid calibration ({e!r}); `nedrt calib --calib {path}` names the field") from e
    eye = raw.get("eye", {})
    lca = eye.get("lca", "off")
    if lca not in ("off", "thibos1992"):
        raise ValueError(f"{path}: eye.lca: {lca!r} is not an eye LCA model (off, thibos1992)")
    pupil = eye.get("pupil_diameter_mm")
    if pupil is not None and not (isinstance(pupil, (int, float)) and 0 < pupil <= 12):
        raise ValueError(f"{path}: eye.pupil_diameter_mm: {pupil!r} must lie in (0, 12] mm")
    relief = eye.get("relief_mm", 15.0)
    if not (isinstance(relief, (int, float)) and 0 <= relief <= 100):
        raise ValueError(f"{path}: eye.relief_mm: {relief!r} must lie in [0, 100] mm")
    if pupil is not None and eye.get("field_deg", 0.0) != 0.0:
        # The trainer's optics are radial: a decentred pupil breaks that.
        raise ValueError(f"{path}: eye.field_deg: the trainer designs on axis (field_deg = 0); "
                         f"docs/model.md §4a")
    cal = dataclasses.replace(cal, eye_pupil_diameter_m=None if pupil is None else pupil * 1e-3,
                              eye_relief_m=relief * 1e-3, eye_lca=lca == "thibos1992")
    for ch in range(len(cal.channels)):
        if cal.lens_distance_m >= cal.focal_length_m(ch):
            raise ValueError(f"{path}: panel.lens_distance_mm: at or beyond the focal length of {cal.channels[ch].name}")
    return cal
