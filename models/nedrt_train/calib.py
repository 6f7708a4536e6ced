"""The calibration (calib/*.toml) and the quantities derived from it,
docs/model.md §2–§5. Field names follow the TOML; values are SI.

The package never looks for the repository: every command takes the
calibration file as an argument (`--calib FILE`, by default
`calib/default.toml` under the current directory, see `resolve`), and the
functions receive the loaded `Calib` or the file's path."""
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

from .paths import resolve_cli_path

#: Where a command looks for the calibration when `--calib` is not given,
#: relative to the current directory (the repository root, usually).
DEFAULT_RELATIVE = Path("calib") / "default.toml"


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

    def focal_length_m(self, ch: int) -> float:
        return self.focal_length_spec_m * (self.index_at_spec - 1) / (self.channels[ch].index - 1)

    def vergence_d(self, ch: int) -> float:
        return 1 / self.lens_distance_m - 1 / self.focal_length_m(ch)

    def psi_rad(self, ch: int, accommodation_d: float) -> float:
        lam = self.channels[ch].wavelength_m
        return math.pi / lam * (self.vergence_d(ch) - accommodation_d) * self.aperture_radius_m ** 2

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
    if "pupil_diameter_mm" in eye or eye.get("lca", "off") != "off":
        # The trainer's optics are the paper's eye (the eyepiece's aperture
        # is the stop, no eye LCA); better refuse than train another model.
        raise ValueError(f"{path}: eye: the trainer models the paper's eye only (no eye.pupil_diameter_mm, "
                         f"eye.lca = \"off\"); docs/model.md §4a")
    for ch in range(len(cal.channels)):
        if cal.lens_distance_m >= cal.focal_length_m(ch):
            raise ValueError(f"{path}: panel.lens_distance_mm: at or beyond the focal length of {cal.channels[ch].name}")
    return cal
