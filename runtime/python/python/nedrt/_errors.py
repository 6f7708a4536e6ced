"""nedrt's exceptions: the Rust library's errors, with its messages."""


class NedrtError(Exception):
    """An error of nedrt: an input it cannot use, or work that failed."""


class InputError(NedrtError, ValueError):
    """A bad argument or input file: a wrong shape or dtype, a NaN, a
    missing design or calibration, a value out of range. The message names
    it and says why."""
