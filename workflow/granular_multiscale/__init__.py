"""Data-driven multiscale modelling of granular materials: FEM–DEM and history-variable FEM–ML.

The FEM solver (``fem``) never knows what sits at its Gauss points: everything that maps a
trial strain to stress and tangent is a material-point set (``materials.base``).
No module of this package imports snakemake; rule scripts under ``scripts/`` are thin.
"""

__version__ = "0.1.0"
