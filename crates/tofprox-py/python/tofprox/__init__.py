"""tofprox from Python: recordings, depth processing and the model lab (docs/python.md).

A thin binding over the same Rust libraries the ``tofprox`` command line uses: results are
the content its ``--json`` prints, as dicts and lists, with images as numpy arrays.
"""

from . import lab
from ._tofprox import Error, Recording, __version__, process

__all__ = ["Error", "Recording", "__version__", "lab", "process"]
