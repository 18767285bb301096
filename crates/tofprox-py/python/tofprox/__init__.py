"""tofprox from Python: recordings, calibration sets, depth processing, the physical model and
the model lab (docs/python.md).

A thin binding over the same Rust libraries the ``tofprox`` command line uses: results are
the content its ``--json`` prints, as dicts and lists, with images as numpy arrays.
"""

from . import lab
from ._tofprox import (
    Calibration,
    Error,
    Model,
    Recording,
    __version__,
    effects,
    process,
    simulate,
    sweep,
)

__all__ = [
    "Calibration",
    "Error",
    "Model",
    "Recording",
    "__version__",
    "effects",
    "lab",
    "process",
    "simulate",
    "sweep",
]
