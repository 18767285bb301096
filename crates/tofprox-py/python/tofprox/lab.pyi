from os import PathLike
from typing import Any, Optional, Union

_Path = Union[str, PathLike[str]]

def compare(
    recording_dir: _Path, model: _Path, hold_effects: bool = False, arrays: bool = False
) -> dict[str, Any]:
    """Fit ``model``'s enabled effects to the recording: ``tofprox lab compare --json``.
    ``arrays=True`` adds ``"arrays"``: what ``--export DIR`` writes as .npy files, as numpy
    arrays (``residual_lsb``, ``residual_z``: float32 captures × K × rows × cols, NaN where a
    code is not in the fit; ``pixel_chi2``, ``offset_lsb``, ``gain_lsb``, ``phase_rad``:
    float64 rows × cols); per capture, unpadded, the lists ``predicted_codes`` (float32
    K × rows × cols), ``measured_depth_mm`` and ``predicted_depth_mm`` (float32 rows × cols,
    NaN where a capture has no depth); and ``captures``, the per-capture table (a list of
    dicts: ``capture``, ``conditions``, ``exposure_us``, ``raw_images``, ``algorithm``,
    ``used``, ``samples``, ``chi2``, ``chi2_share``, ``rms_residual_lsb``,
    ``depth_rms_mm``)."""

def diagnose(
    recording_dir: _Path,
    model: _Path,
    tolerance_mm: Optional[float] = None,
    arrays: bool = False,
) -> dict[str, Any]:
    """Rank the effects ``model`` lacks and give a verdict: ``tofprox lab diagnose --json``
    (``arrays=True``: the comparison's arrays under ``"arrays"``, as ``compare``)."""

def add(
    effect: str,
    model: _Path,
    data: _Path,
    out: Optional[_Path] = None,
    force: bool = False,
    hold: Union[dict[str, float], list[str], None] = None,
) -> dict[str, Any]:
    """Enable ``effect``, fit it on the recording ``data``, write the model to ``out``:
    ``tofprox lab add --json`` (errors before and after, how much of the depth error is
    systematic under ``depth_error``, fitted parameters). ``hold``: the model file's
    parameters to hold while the others are fitted, ``{name: value}`` or a list of names
    (held at the file's values), as ``--hold NAME[=VALUE]``; ``held`` gives them back."""

def explain(
    recording_dir: _Path,
    model: _Path,
    out: Optional[_Path] = None,
    force: bool = False,
    tolerance_mm: Optional[float] = None,
) -> dict[str, Any]:
    """Loop diagnose → add until nothing is missing: ``tofprox lab explain --json``."""
