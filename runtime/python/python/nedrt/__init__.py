"""nedrt: the simulator, prefilters, PSFs and evaluation of a computational
multifocal near-eye display (a lens and a static DOE focus the panel at
0.5, 1.5 and 2.5 D), on numpy arrays.

    import numpy as np, nedrt
    display = nedrt.Display(design="multifocal")            # from the repository root
    image = np.random.default_rng(0).random((64, 64, 3), dtype=np.float32)
    seen = display.perceived(image, 1.0, method="doe+wiener", prefilter="refine:10")

Images are H×W×3 float32 arrays in [0, 1]; perceived images are on the
retinal grid (2H×2W×3). Each call gives what the `nedrt` command gives for
the same input (`nedrt sim`, `nedrt psf`, `nedrt eval`); docs in the
repository's docs/python.md.
"""
from ._errors import InputError, NedrtError
from ._nedrt import Display, __version__

__all__ = ["Display", "InputError", "NedrtError", "__version__"]
