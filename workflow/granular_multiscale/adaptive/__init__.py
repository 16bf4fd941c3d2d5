"""Adaptive FEM–DEM–ML: a material-point set that answers from the surrogate where it is sure and
from a YADE RVE where it is not (``material.AdaptiveMaterialPointSet``). Above ``dem/`` and
``surrogate/``, below the drivers (``drivers.adaptive`` runs it); it never imports the solver.

Importing the package itself is light (no torch): the rule files use :func:`threshold_label`."""

import math


def threshold_label(threshold: float) -> str:
    """Folder name of a threshold: 't0.05', 't0', 'tinf'."""
    return "tinf" if math.isinf(threshold) else f"t{threshold:g}"
