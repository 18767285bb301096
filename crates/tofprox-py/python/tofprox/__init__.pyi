from os import PathLike
from typing import Any, Optional, Sequence, Union

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
    @staticmethod
    def write(
        path: _Path,
        sensor: dict[str, Any],
        captures: Sequence[dict[str, Any]],
        frames: Sequence[npt.NDArray[Any]],
        description: Optional[str] = None,
        force: bool = False,
    ) -> "Recording":
        """Write a new recording from arrays and return it, opened. ``sensor`` as
        ``Recording.sensor``; ``captures`` as ``Recording.captures`` (``phases_deg``,
        ``exposure_us``, optional ``illumination``, ``averaged``, ``timestamp_ns``,
        ``conditions``; ``frames`` ignored); ``frames`` one (images, rows, cols) array per
        capture, uint16, float32 or float64. Checked as a reader checks it before anything is
        written (``tofprox.Error`` with ``kind`` and ``key``); an existing recording is replaced
        only with ``force=True``."""

class Calibration:
    """A calibration set directory, verified when loaded (checksums, shapes, dependencies)."""

    def __init__(self, path: _Path) -> None: ...
    @property
    def path(self) -> Optional[str]:
        """The set's directory."""
    @property
    def description(self) -> Optional[str]:
        """The set's description."""
    @property
    def parts(self) -> list[str]:
        """The parts present (``offset``, ``wiggling_2phase``, ``fppn``, ``amplitude``, …)."""
    @property
    def valid_for(self) -> dict[str, Any]:
        """The sensor setup and window the set was extracted on."""
    @property
    def intrinsics(self) -> Optional[dict[str, Any]]:
        """The lens intrinsics, None without them."""
    @property
    def sources(self) -> dict[str, dict[str, Any]]:
        """Part name → provenance (``recording``, ``captures``, ``distance_m``, ``created``, …)."""
    @property
    def arrays(self) -> dict[str, npt.NDArray[np.float32]]:
        """Part name → its table: ``offset`` (rows, cols) LSB, ``crosstalk`` (phases, rows,
        cols) LSB/µs, ``wiggling_2phase``/``wiggling_4phase`` (LUT) rad, ``fppn``/
        ``fppn_2phase`` (rows, cols) rad, ``amplitude`` (rows, cols) LSB·m²/µs."""

class Model:
    """A model file (``config/model/*.toml``), validated when loaded."""

    def __init__(self, path: _Path) -> None: ...
    @property
    def path(self) -> str:
        """The model file."""
    @property
    def description(self) -> Optional[str]:
        """The file's description."""
    @property
    def enabled(self) -> list[str]:
        """The ids of the enabled effects, in catalogue order."""
    @property
    def effects(self) -> dict[str, dict[str, Any]]:
        """Every catalogue effect: id → ``{"enabled": bool, "params": {name: value}}``."""
    @property
    def sensor(self) -> dict[str, float]:
        """The ``[sensor]`` parameters the file sets."""
    def summary(self) -> dict[str, Any]:
        """The dict ``tofprox model show --json`` prints."""

def effects() -> list[dict[str, Any]]:
    """The effect catalogue as ``tofprox model effects --json`` prints it: ``id``, ``title``,
    ``thesis_ref``, ``acts_on``, ``drivers``, ``params`` (``name``, ``unit``, ``typical``,
    ``min``, ``max``, ``doc``), …"""

def simulate(
    model: _Path,
    distances_m: Sequence[float],
    exposure_us: float = 1000.0,
    phases: int = 4,
    reflectivity: float = 0.9,
    ambient_klux: float = 0.0,
    temperature_c: float = 25.0,
    averaged: int = 1,
    illumination: bool = True,
    window: Optional[tuple[int, int, int, int]] = None,
    seed: int = 1,
) -> npt.NDArray[Any]:
    """One capture of a flat wall at each distance, shape (distances, images, rows, cols):
    uint16 ADC codes for single acquisitions of a quantising model, float32 otherwise.
    ``window`` is (row, col, height, width) on the 172×224 array (None: all of it)."""

def sweep(
    model: _Path,
    out: Optional[_Path] = None,
    distances_m: Optional[Sequence[float]] = None,
    exposures_us: Optional[Sequence[float]] = None,
    phases: Optional[int] = None,
    ambient_klux: Optional[Sequence[float]] = None,
    temperatures_c: Optional[Sequence[float]] = None,
    reflectivity: Optional[float] = None,
    repeats: Optional[int] = None,
    averaged: Optional[int] = None,
    correlation_distance_m: Optional[float] = None,
    window: Optional[tuple[int, int, int, int]] = None,
    seed: int = 1,
    like: Optional[_Path] = None,
    force: bool = False,
) -> Union[Recording, tuple[list[dict[str, Any]], list[npt.NDArray[Any]]]]:
    """A calibration-session-like sweep, as ``tofprox sim sweep`` (None: its defaults), or the
    captures of the recording ``like`` under their own conditions. With ``out``: written
    there (the CLI's bytes, but the description) and returned as a ``Recording``; without:
    ``(captures, frames)`` as ``Recording.write`` takes them."""

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
