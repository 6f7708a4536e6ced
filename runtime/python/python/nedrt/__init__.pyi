"""Type stubs of nedrt (the extension module nedrt._nedrt re-exported)."""
from os import PathLike
from typing import Any, Dict, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

__version__: str

_Path = Union[str, PathLike]

class NedrtError(Exception): ...
class InputError(NedrtError, ValueError): ...

class Display:
    """A display of nedrt: its calibration, design (a DOE with its Wiener
    K), eye and networks, as the `nedrt` command's global options give them.

    calib: a calibration TOML (default: nedrt's embedded one). design: a
    design by name (designs/NAME.toml under the working directory) or file.
    eye: "paper", "4mm", "3mm+lca", "4mm@10". doe: a DOE file over the
    calibration's. dcnn: the network of `proposed` (ONNX, or an unrolled
    model's manifest). backend: "cpu", "ort" or "wgpu". cache: keep PSFs in
    nedrt's cache folder ($NEDRT_CACHE_DIR, ~/.cache/nedrt).
    """

    def __init__(
        self,
        calib: Optional[_Path] = None,
        design: Optional[str] = None,
        eye: Optional[str] = None,
        doe: Optional[_Path] = None,
        dcnn: Optional[_Path] = None,
        backend: str = "cpu",
        cache: bool = True,
    ) -> None: ...
    @property
    def panel(self) -> Tuple[int, int]:
        """The panel's size in pixels, (width, height)."""
    def perceived(
        self,
        image: npt.NDArray[np.float32],
        accommodation_d: float,
        method: Optional[str] = None,
        prefilter: str = "native",
    ) -> npt.NDArray[np.float32]:
        """What the eye sees of `image` (H×W×3 float32 in [0, 1]) at
        `accommodation_d` diopters: 2H×2W×3, as `nedrt sim --out` writes it.
        method: conventional, ai, doe-only, doe+wiener, proposed, lens+dcnn
        (default: the shipped one). prefilter: native, lsq, refine:K,
        admm:K, optimal (@sharp or @target)."""
    def prefilter(
        self,
        image: npt.NDArray[np.float32],
        method: Optional[str] = None,
        prefilter: str = "refine:10",
    ) -> npt.NDArray[np.float32]:
        """The display image (H×W×3 in [0, 1]) of `image` with `prefilter`
        on the method's optics, as `nedrt sim --display-out` writes it."""
    def psfs(self, accommodation_d: float, method: Optional[str] = None) -> npt.NDArray[np.float64]:
        """The method's PSFs at `accommodation_d` diopters: C×N×N, each cell
        the fraction of the light in it on the retinal grid, the axis at the
        centre (the rest, 1 − the sum, is a uniform veil)."""
    def evaluate(
        self,
        images: _Path,
        methods: Optional[Sequence[str]] = None,
        prefilters: Sequence[str] = ("native",),
        designs: Sequence[str] = (),
        out_dir: Optional[_Path] = None,
    ) -> Dict[str, Any]:
        """`nedrt eval` on a folder of images: its eval.json as a dict."""
