"""Material-point sets: everything that maps trial strains at Gauss points to stress and tangent."""

from .base import MaterialPointSet, MaterialPointError

__all__ = ["MaterialPointSet", "MaterialPointError"]
