"""The data contract: one self-describing HDF5 file per FEM run (xarray, engine h5netcdf).

Coordinates
    step   load step, 0 = consolidated initial state
    gp     Gauss point, index = element * 8 + quadrature point
    comp   Voigt labels "11","22","33","23","13","12" (tensors.COMP)
    tcomp  21 labels of the upper triangle of the 6×6 tangent (tensors.TCOMP)
    hist   "phi1","phi2","phi3" (history.HIST)
    node, xyz ("x","y","z"), iteration (Newton iteration within a step)

Variables (units in each variable's attrs)
    strain(step,gp,comp)        total small strain, tensorial shear, tension positive
    stress(step,gp,comp)        Pa, tension positive
    tangent(step,gp,tcomp)      Pa, upper triangle of dσ/d(engineering ε) at the converged state
    history(step,gp,hist)       φ1–φ3 of the converged strains
    gp_position(gp,xyz), node_position(node,xyz), displacement(step,node,xyz)   m
    axial_strain(step)          compression positive
    top_force(step)             N, tension positive (= ∫σzz over the top face)
    volumetric_strain(step)     tension positive
    newton_iterations(step), residual_norm(step,iteration), cutbacks(step), wall_time(step), phase(step)

Global attrs: ``method`` (what sat at the Gauss points), ``config`` (YAML of the config that
produced the file), ``sign_convention``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import xarray as xr
import yaml

from .atomic import atomic_path

ENGINE = "h5netcdf"

#: variables every run file must hold (readers may rely on them)
REQUIRED_VARIABLES = (
    "strain",
    "stress",
    "tangent",
    "history",
    "gp_position",
    "node_position",
    "displacement",
    "axial_strain",
    "top_force",
    "volumetric_strain",
    "newton_iterations",
    "wall_time",
)

SIGN_CONVENTION = (
    "stress and strain tension positive; strain tensorial (eps23, not gamma23); "
    "axial_strain compression positive; top_force tension positive (integral of sigma_zz over the top face); "
    "tangent acts on the engineering strain [e11,e22,e33,2e23,2e13,2e12]"
)


class DataFileError(OSError):
    """A run file is missing, unreadable, truncated or lacks a variable; the message names the file."""


def write_run(ds: xr.Dataset, path: str | Path, config: dict | None = None) -> Path:
    """Write a run Dataset atomically (temporary file in the same folder, then rename).

    A failure while writing never leaves a half-written file at ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    ds = ds.copy()
    if config is not None:
        ds.attrs["config"] = yaml.safe_dump(config, sort_keys=False)
    ds.attrs.setdefault("sign_convention", SIGN_CONVENTION)
    missing = [v for v in REQUIRED_VARIABLES if v not in ds.variables]
    if missing:
        raise ValueError(f"refusing to write {path}: the run lacks variables {missing}")
    with atomic_path(path) as tmp:
        ds.to_netcdf(tmp, engine=ENGINE, invalid_netcdf=True)
    return path


def read_run(path: str | Path, required=REQUIRED_VARIABLES) -> xr.Dataset:
    """Read a run file fully into memory; :class:`DataFileError` naming the file if it cannot be used."""
    path = Path(path)
    if not path.is_file():
        raise DataFileError(f"run file {path} does not exist")
    try:
        with xr.open_dataset(path, engine=ENGINE) as ds:
            ds = ds.load()
    except Exception as error:  # h5py/h5netcdf raise OSError, ValueError, KeyError... on damaged files
        raise DataFileError(f"run file {path} is not a readable HDF5/netCDF file (truncated or corrupt?): {error}") from error
    missing = [v for v in required if v not in ds.variables]
    if missing:
        raise DataFileError(f"run file {path} lacks variables {missing}")
    for name in ("strain", "stress"):
        if name in ds and not np.isfinite(ds[name].values).all():
            raise DataFileError(f"run file {path}: variable '{name}' holds non-finite values")
    return ds


def run_config(ds: xr.Dataset) -> dict | None:
    """The config stored in a run file's attrs (None if absent)."""
    text = ds.attrs.get("config")
    return yaml.safe_load(text) if text else None
