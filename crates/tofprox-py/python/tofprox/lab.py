"""The model lab: compare a model file with a recording, diagnose the missing effect, add it,
or loop diagnose → add (explain). Each returns the dict ``tofprox lab … --json`` prints."""

from ._tofprox import lab as _lab

compare = _lab.compare
diagnose = _lab.diagnose
add = _lab.add
explain = _lab.explain

__all__ = ["add", "compare", "diagnose", "explain"]
