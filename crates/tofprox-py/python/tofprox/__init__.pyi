from os import PathLike
from typing import Any, Optional, Union

import numpy as np
import numpy.typing as npt

from . import lab as lab

__version__: str

_Path = Union[str, PathLike[str]]

class Error(Exception):
    """A tofprox error; str(e) is the message the command line prints."""

    kind: str
    """What went wrong: the Rust error kind (``MissingKey``, ``Invalid``, ``Incompatible``,
    ``Npy``, ``Io``, ``NeedsLens``, ``NothingToProcess``, ``UnknownEffect``, ``InvalidModel``, …)."""
    file: Optional[str]
    """The file the error is about, if known."""
    key: Optional[str]
    """The key inside it (``capture[3].phases_deg``, ``valid_for``), if known."""

class Recording:
    """A raw recording (``REC/recording.toml`` + ``REC/frames/*.npy``), validated when opened."""

    def __init__(self, path: _Path) -> None: ...
    @property
    def path(self) -> str:
        """The recording's directory."""
    @property
    def sensor(self) -> dict[str, Any]:
        """The ``[sensor]`` table: window, full array, ADC bits, modulation frequency."""
    @property
    def captures(self) -> list[dict[str, Any]]:
        """One dict per ``[[capture]]`` table of recording.toml, in order."""
    def frames(self, index: int) -> npt.NDArray[Any]:
        """Capture ``index``'s raw images, shape (images, rows, cols): uint16 ADC codes, or
        float32/float64 averaged codes."""
    def __len__(self) -> int: ...

def process(
    recording_dir: _Path,
    calib: Optional[_Path] = None,
    algo: str = "2phase",
    depth_kind: str = "radial",
    min_amplitude_lsb: Optional[float] = None,
) -> list[dict[str, Any]]:
    """Process every capture ``algo`` (``"2phase"``/``"4phase"``) can evaluate, as
    ``tofprox process --json``: one dict per capture with that row's keys (``index``,
    ``depth_kind``, ``distance_m``, ``median_depth_m``, ``error_mm``, ``valid_fraction``,
    ``process_us``[, ``crosstalk_residual``]) plus ``depth_mm`` (uint16, 0 = invalid) and
    ``amplitude_lsb`` (float32) arrays of shape (rows, cols)."""
