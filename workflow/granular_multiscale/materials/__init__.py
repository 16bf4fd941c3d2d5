"""Material-point sets: everything that maps trial strains at Gauss points to stress and tangent."""

from .base import MaterialPointError, MaterialPointSet
from .elastic import LinearElastic
from .elastoplastic import Elastoplastic

__all__ = ["MaterialPointSet", "MaterialPointError", "LinearElastic", "Elastoplastic", "make_material"]


def make_material(name: str, n_points: int, config: dict) -> MaterialPointSet:
    """Material-point set by name, parameters from the config section of the same name.

    The analytic sets start from the consolidated state −p0·1 (p0 = specimen.confining_pressure)."""
    if name == "linear_elastic":
        p0 = config["specimen"]["confining_pressure"]
        return LinearElastic.from_config(n_points, config, initial_stress=[-p0, -p0, -p0, 0.0, 0.0, 0.0])
    if name == "elastoplastic":
        return Elastoplastic.from_config(n_points, config)
    raise ValueError(f"unknown material-point set {name!r}; known: 'linear_elastic', 'elastoplastic'")
