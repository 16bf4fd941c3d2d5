"""The data contract: one self-describing HDF5 file per FEM run (xarray, engine h5netcdf).

Every problem (attribute ``problem``: triaxial, biaxial, footing; ``fem/``) writes the same
variables; each adds its own observables. Plane-strain problems (attribute ``plane_strain`` 1)
lie in the x–z plane (z vertical as in the triaxial specimen, y = 0 out of plane), their strains
have ε_yy = γ_xy = γ_yz = 0 and their forces are per metre of thickness (units N/m).

Coordinates
    step   load step, 0 = consolidated initial state
    gp     Gauss point, index = element * k + quadrature point (k = attribute
           ``gauss_points_per_element``: 8 hexahedra, 4 quadrilaterals)
    comp   Voigt labels "11","22","33","23","13","12" (tensors.COMP)
    tcomp  21 labels of the upper triangle of the 6×6 tangent (tensors.TCOMP)
    tcomp36  36 labels of the full 6×6 tangent, row by row (tensors.TCOMP36); only in a run
           whose tangent is not symmetric
    hist   "phi1","phi2","phi3","psi1","psi2" (history.HIST)
    node   vertices, then (quadratic elements) mid-side nodes; xyz ("x","y","z")
    element, vertex   the elements and their vertex nodes; iteration (Newton iteration within a step)

Variables (units in each variable's attrs)
    strain(step,gp,comp)        total small strain, tensorial shear, tension positive
    stress(step,gp,comp)        Pa, tension positive
    tangent(step,gp,tcomp)      Pa, upper triangle of dσ/d(engineering ε) at the converged state
                                (of its symmetric part ½(D + Dᵀ) when the tangent is not symmetric)
    tangent_full(step,gp,tcomp36)  Pa, only when the tangent is not symmetric: all of it
    history(step,gp,hist)       φ1–φ3, ψ1, ψ2 of the converged strains
    gp_position(gp,xyz), node_position(node,xyz), displacement(step,node,xyz)   m
    element_vertices(element,vertex)   node indices, scikit-fem's local vertex order
    load_displacement(step)     m, displacement of the loaded boundary along the load (downwards
                                positive); = the load path's value × attribute load_length_m
    load_force(step)            reaction of the loaded boundary along the load, compression positive;
                                N (3D) or N/m (plane strain); its description says of what
    volumetric_strain(step)     tension positive (plane strain: area change / area)
    newton_iterations(step), residual_norm(step,iteration), cutbacks(step), wall_time(step), phase(step)

Per problem (units and signs in each variable's attrs; attributes ``load_measure``, ``load_length_m``)
    triaxial  axial_strain(step) compression positive; top_force(step) N, tension positive
              (= ∫σzz over the top face = −load_force), the names users' scripts read
    biaxial   axial_strain(step); top_force(step) N/m, tension positive; lateral_strain(step)
    footing   settlement_ratio(step) s/B; footing_pressure(step) Pa, compression positive

Tangents. The file holds the tangent the solver used at each converged state (after
``newton.tangent_repair`` where configured), without loss: a symmetric one (to round-off,
``tensors.SYMMETRY_RTOL``: DEM, elastoplastic, elastic, ND) in its 21 entries ``tangent``; one
that is not (FEM–ML with the autodiff tangent: the exact Jacobian of NNσ) also in all 36,
``tangent_full``, and then ``tangent`` is the upper triangle of its symmetric part — what a
symmetric representation (ND's 21 targets, positive-definiteness checks) should see. Attrs
``tangent_symmetric`` (1/0), ``tangent_asymmetry`` (largest max|D − Dᵀ|/max|D|) and
``tangent_variable`` (the variable holding the solver's tangent) say which;
:func:`run_tangent` returns the 6×6 tangents of any run file, old or new.

Global attrs: ``method`` (what sat at the Gauss points), ``config`` (YAML of the config that
produced the file), ``sign_convention``.

RVE-path files (``{output_dir}/rve_paths/{set}.h5``, method "rve_paths", no FEM: RVEs driven
along designed strain histories, ``drivers.rve_paths``) hold one ``gp`` per trajectory and
:data:`RVE_PATHS_VARIABLES`: strain, stress, tangent (21), history as above, plus
``family(gp)``, ``valid(step,gp)`` (False from the step an RVE lost its contact network on;
its stress and tangent are NaN there, never zeros), ``lost_contact_step(gp)`` (−1 = never),
``particle_steps(step)`` and ``wall_time(step)``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import xarray as xr
import yaml

from . import integrity
from .atomic import atomic_path
from .tensors import SYMMETRY_RTOL, TCOMP36, symmetric_part, tangent_asymmetry, tangent_from_full, \
    tangent_from_upper, tangent_to_full, tangent_to_upper

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
    "load_displacement",
    "load_force",
    "volumetric_strain",
    "newton_iterations",
    "wall_time",
)
#: variables of an RVE-path file (no FEM: no displacement, platen force or Newton records)
RVE_PATHS_VARIABLES = ("strain", "stress", "tangent", "history", "family", "valid", "lost_contact_step",
                       "particle_steps", "wall_time")

SIGN_CONVENTION = (
    "stress and strain tension positive; strain tensorial (eps23, not gamma23); "
    "axial_strain compression positive; top_force tension positive (integral of sigma_zz over the top face); "
    "tangent acts on the engineering strain [e11,e22,e33,2e23,2e13,2e12]"
)


class DataFileError(OSError):
    """A run file is missing, unreadable, truncated or lacks a variable; the message names the file."""


def write_run(ds: xr.Dataset, path: str | Path, config: dict | None = None, required=REQUIRED_VARIABLES) -> Path:
    """Write a run Dataset atomically (temporary file in the same folder, then rename); it must
    hold the ``required`` variables (an RVE-path file: :data:`RVE_PATHS_VARIABLES`).

    A failure while writing never leaves a half-written file at ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    ds = ds.copy()
    if config is not None:
        ds.attrs["config"] = yaml.safe_dump(config, sort_keys=False)
    ds.attrs.setdefault("sign_convention", SIGN_CONVENTION)
    missing = [v for v in required if v not in ds.variables]
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
        integrity.verify(path, "run file")
    except integrity.CorruptFileError as error:
        raise DataFileError(str(error)) from None
    try:
        with xr.open_dataset(path, engine=ENGINE) as ds:
            ds = ds.load()
    except Exception as error:  # h5py/h5netcdf raise OSError, ValueError, KeyError... on damaged files
        raise DataFileError(f"run file {path} is not a readable HDF5/netCDF file (truncated or corrupt?): {error}") from error
    ds = _with_load_variables(ds)
    missing = [v for v in required if v not in ds.variables]
    if missing:
        raise DataFileError(f"run file {path} lacks variables {missing}")
    # an RVE-path set marks the steps after an RVE lost its contact network: valid False, stress NaN
    valid = ds["valid"].transpose("step", "gp").values.astype(bool) if "valid" in ds else None
    for name in ("strain", "stress"):
        if name in ds:
            finite = np.isfinite(ds[name].transpose("step", "gp", ...).values).all(axis=-1)
            if not (finite | ~valid).all() if valid is not None else not finite.all():
                raise DataFileError(f"run file {path}: variable '{name}' holds non-finite values")
    return ds


def _with_load_variables(ds: xr.Dataset) -> xr.Dataset:
    """A triaxial run written before every run held ``load_force`` and ``load_displacement`` gets
    them from its ``top_force`` and ``axial_strain`` (what every run now writes for itself)."""
    if "load_force" in ds or "top_force" not in ds or "axial_strain" not in ds or "specimen_size_m" not in ds.attrs:
        return ds
    height = float(np.asarray(ds.attrs["specimen_size_m"])[2])
    return ds.assign(
        load_force=(("step",), -ds["top_force"].values, {"units": "N", "description": "-top_force"}),
        load_displacement=(("step",), ds["axial_strain"].values * height, {"units": "m"}),
    )


def run_config(ds: xr.Dataset) -> dict | None:
    """The config stored in a run file's attrs (None if absent)."""
    text = ds.attrs.get("config")
    return yaml.safe_load(text) if text else None


# -- tangents -------------------------------------------------------------------------------
def _as_matrices(tangents) -> np.ndarray:
    """Per-step tangents [gp, 6, 6] (or [gp, 21], a record of an older checkpoint) -> [step, gp, 6, 6]."""
    steps = [np.asarray(t, dtype=float) for t in tangents]
    return np.stack([tangent_from_upper(t) if t.shape[-1] == 21 else t for t in steps])


def tangent_variables(tangents, used: str = "as the material set returned it") -> tuple[dict, dict]:
    """The run file's tangent variables for the tangents the solver used, per step [gp, 6, 6].

    Returns ({name: (dims, values, units, description)}, global attrs): ``tangent`` alone when
    every tangent is symmetric to round-off, else ``tangent`` (upper triangle of the symmetric
    part) and ``tangent_full`` (all 36 entries; the caller adds the coordinate
    ``tcomp36 = tensors.TCOMP36``). `used` says where the tangent comes from (e.g. after a
    tangent repair) and goes into the descriptions."""
    D = _as_matrices(tangents)
    asymmetry = tangent_asymmetry(D)
    symmetric = asymmetry <= SYMMETRY_RTOL
    what = (f"the Voigt tangent D = d(stress)/d(engineering strain) of the converged state as the solver had it "
            f"(the stiffness of the next step's predictor), {used}")
    variables = {}
    if symmetric:
        variables["tangent"] = (("step", "gp", "tcomp"), tangent_to_upper(D), "Pa",
                                f"upper triangle of {what}; symmetric (relative asymmetry {asymmetry:.1e} <= "
                                f"{SYMMETRY_RTOL:.0e}), so these 21 entries hold all of it")
    else:
        variables["tangent"] = (("step", "gp", "tcomp"), tangent_to_upper(symmetric_part(D)), "Pa",
                                f"upper triangle of the SYMMETRIC PART (D + D^T)/2 of {what}; D is not symmetric "
                                f"(largest relative asymmetry {asymmetry:.3g}): D itself is tangent_full")
        variables["tangent_full"] = (("step", "gp", "tcomp36"), tangent_to_full(D), "Pa",
                                     f"{what}; not symmetric (largest relative asymmetry {asymmetry:.3g}), all 36 "
                                     "entries row by row: tcomp36 'IJ' (Voigt pairs I, J) is D[I, J]")
    attrs = {"tangent_symmetric": int(symmetric), "tangent_asymmetry": asymmetry,
             "tangent_variable": "tangent" if symmetric else "tangent_full"}
    return variables, attrs


def run_tangent(ds: xr.Dataset) -> np.ndarray:
    """[step, gp, 6, 6]: the tangent the solver used, from ``tangent_full`` when the run has it,
    else the 21 entries of ``tangent`` (a symmetric tangent, or a file written before
    ``tangent_full`` existed, whose lower triangle is lost)."""
    if "tangent_full" in ds:
        full = ds["tangent_full"].transpose("step", "gp", "tcomp36")
        if [str(c) for c in full.tcomp36.values] != list(TCOMP36):
            raise DataFileError(f"coordinate 'tcomp36' is {list(full.tcomp36.values)}, expected {list(TCOMP36)}")
        return tangent_from_full(full.values)
    return tangent_from_upper(ds["tangent"].transpose("step", "gp", "tcomp").values)
