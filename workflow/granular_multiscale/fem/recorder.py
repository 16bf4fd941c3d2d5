"""The recorder of a run: what the step loop hands it per converged load step, and the
data-contract Dataset it makes of that (``granular_multiscale.data``).

The step loop (:meth:`fem.problem.BoundaryValueProblem.run`) calls :meth:`RunRecorder.record`
once per load step with the converged state; the recorder knows nothing of the solver and the
solver nothing of the file format. The history variables φ1–φ3, ψ1, ψ2 are computed here, from
the converged strains (``history.history_from_sequence``), not by the solver.

``records`` is plain lists of numpy arrays and numbers: the checkpoint pickles it as it is.
"""

from __future__ import annotations

import json

import numpy as np
import xarray as xr

from ..data import tangent_variables
from ..history import HIST, history_from_sequence
from ..tensors import COMP, TCOMP, TCOMP36

#: per-step lists of :attr:`RunRecorder.records`
RECORDS = ("strain", "stress", "tangent", "displacement", "load", "load_force", "volumetric_strain",
           "newton_iterations", "material_evaluations", "tangent_evaluations", "residual_norm", "residual_reference",
           "cutbacks", "wall_time", "step_info", "observables")


class RunRecorder:
    """Collects the converged load steps of one run; :meth:`dataset` writes them in the data contract."""

    def __init__(self, records: dict | None = None):
        self.records = records if records is not None else {k: [] for k in RECORDS}
        missing = [k for k in RECORDS if k not in self.records]
        if missing:
            raise ValueError(f"run records lack {missing} (a checkpoint of another version?)")

    @property
    def n_steps(self) -> int:
        return len(self.records["load"])

    def record(self, *, result, load: float, load_force: float, volumetric_strain: float, displacement: np.ndarray,
               iterations: int, evaluations: int, tangent_evaluations: int, cutbacks: int, wall: float,
               step_info: dict, observables: dict) -> None:
        """One converged load step: the solver's state `result` (``newton.Converged``) and what was measured."""
        r = self.records
        r["strain"].append(result.strain)
        r["stress"].append(result.stress)
        r["tangent"].append(np.array(result.tangent, dtype=float))  # all 36 entries (data.tangent_variables)
        r["displacement"].append(displacement)
        r["load"].append(load)
        r["load_force"].append(load_force)
        r["volumetric_strain"].append(volumetric_strain)
        r["newton_iterations"].append(iterations)
        r["material_evaluations"].append(evaluations)
        r["tangent_evaluations"].append(tangent_evaluations)
        r["residual_norm"].append(list(result.residual_norms))
        r["residual_reference"].append(result.reference)
        r["cutbacks"].append(cutbacks)
        r["wall_time"].append(wall)
        r["step_info"].append(dict(step_info))
        r["observables"].append(dict(observables))

    # -- the Dataset ----------------------------------------------------------------------
    def dataset(self, problem, load_path, method: str, material_points: int) -> xr.Dataset:
        """The data-contract Dataset of the recorded steps (common variables, the problem's
        observables and attributes, the material's step_info)."""
        rec = self.records
        n_steps = self.n_steps
        strain = np.asarray(rec["strain"])
        longest = max(len(r) for r in rec["residual_norm"])
        residuals = np.full((n_steps, longest), np.nan)
        for k, r in enumerate(rec["residual_norm"]):
            residuals[k, : len(r)] = r
        newton = problem.newton
        repair = newton.tangent_repair
        tangent_vars, tangent_attrs = tangent_variables(rec["tangent"], (
            "as the material set returned it" if repair == "none" else
            f"after newton.tangent_repair '{repair}' (eigenvalue floor {newton.tangent_floor:g} x the largest): "
            "points whose tangent was repaired (tangent_repaired_points per step) hold the floored symmetric "
            "matrix, the others the material's own tangent"))
        per_element = problem.ops.points_per_element
        coords = {
            "step": np.arange(n_steps),
            "gp": np.arange(problem.n_gauss_points),
            "comp": list(COMP),
            "tcomp": list(TCOMP),
            **({"tcomp36": list(TCOMP36)} if "tangent_full" in tangent_vars else {}),
            "hist": list(HIST),
            "node": np.arange(problem.ops.n_nodes),
            "xyz": ["x", "y", "z"],
            "iteration": np.arange(longest),
            "vertex": np.arange(problem.ops.element_vertices().shape[1]),
        }
        force = problem.load_force_meaning()
        v = {
            "strain": (("step", "gp", "comp"), strain, "1", "total small strain, tensorial shear, tension positive"),
            "stress": (("step", "gp", "comp"), np.asarray(rec["stress"]), "Pa", "Cauchy stress, tension positive"),
            **tangent_vars,  # tangent, and tangent_full when it is not symmetric
            "history": (("step", "gp", "hist"), history_from_sequence(strain), "1",
                        "history variables phi1-phi3, psi1, psi2 of the converged strains"),
            "gp_position": (("gp", "xyz"), problem.gp_positions, "m",
                            f"Gauss point coordinates (gp = element*{per_element} + q)"),
            "node_position": (("node", "xyz"), problem.node_positions, "m", "node coordinates"),
            "element_vertices": (("element", "vertex"), problem.ops.element_vertices(), "",
                                 "vertex nodes of each element (scikit-fem's local order; gp = element*"
                                 f"{per_element} + q)"),
            "displacement": (("step", "node", "xyz"), np.asarray(rec["displacement"]), "m", "nodal displacement"),
            "load_displacement": (("step",), np.asarray(rec["load"]) * problem.load_length, "m",
                                  f"displacement of the loaded boundary ({problem.loaded_boundary}) along the "
                                  "load, positive in compression (downwards)"),
            "load_force": (("step",), np.asarray(rec["load_force"]), force["units"], force["description"]),
            "volumetric_strain": (("step",), np.asarray(rec["volumetric_strain"]), "1",
                                  f"volume change / volume of the {problem.domain_name}, tension positive"
                                  + ("; plane strain: area change / area" if problem.ops.dim == 2 else "")),
            "newton_iterations": (("step",), np.asarray(rec["newton_iterations"], dtype=np.int64), "1",
                                  "Newton corrections of the converged (sub-)steps"),
            "material_evaluations": (("step",), np.asarray(rec["material_evaluations"], dtype=np.int64), "1",
                                     "material-set evaluations, failed attempts included"),
            "tangent_evaluations": (("step",), np.asarray(rec["tangent_evaluations"], dtype=np.int64), "1",
                                    "material-set evaluations that asked for the tangent (fewer with modified Newton)"),
            "residual_norm": (("step", "iteration"), residuals, "N",
                              "norm of the out-of-balance force on free dofs per iteration of the last "
                              "(sub-)step (iteration 0 = after the predictor); NaN-padded"),
            "residual_reference": (("step",), np.asarray(rec["residual_reference"]), "N",
                                   "max(|f_ext|, |reaction|): convergence when residual_norm <= tolerance * this"),
            "residual_relative": (("step",), np.asarray([r[-1] for r in rec["residual_norm"]]) /
                                  np.asarray(rec["residual_reference"]), "1",
                                  "relative residual the step was accepted at (its last residual_norm / "
                                  "residual_reference; at most the attribute newton_tolerance)"),
            "cutbacks": (("step",), np.asarray(rec["cutbacks"], dtype=np.int64), "1", "times the step was halved"),
            "wall_time": (("step",), np.asarray(rec["wall_time"]), "s", "wall time of the step"),
            "phase": (("step",), np.asarray(load_path.phase()[:n_steps], dtype=str), "",
                      "initial, loading, unloading or reloading"),
        }
        for name, (units, description) in problem.observable_meanings().items():
            v[name] = (("step",), np.asarray([o[name] for o in rec["observables"]], dtype=float), units, description)
        info_keys = sorted({k for d in rec["step_info"] for k in d})
        for key in info_keys:
            if key in v:
                raise ValueError(f"material step_info key {key!r} clashes with a data-contract variable")
            values = np.asarray([d.get(key, np.nan) for d in rec["step_info"]], dtype=float)
            v[key] = (("step",), values, "", f"material step_info '{key}'")
        data_vars = {}
        for name, (dims, values, units, description) in v.items():
            attrs = {"description": description}
            if units:
                attrs["units"] = units
            data_vars[name] = xr.Variable(dims, values, attrs)
        return xr.Dataset(
            data_vars,
            coords=coords,
            attrs={
                "method": method,
                "problem": problem.name,
                "load_path": load_path.name,
                "load_path_segments": json.dumps([list(s) for s in load_path.segments]),
                "load_measure": problem.load_measure,
                "load_length_m": problem.load_length,
                "element": problem.ops.element,
                "plane_strain": int(problem.ops.dim == 2),
                **problem.attributes(),
                "confining_pressure_Pa": problem.confining_pressure,
                "modelled_fraction": 1.0 / problem.force_factor,
                "uniform_field": int(problem.uniform_field),
                "material_points": int(material_points),
                "newton_tolerance": newton.tolerance,
                "newton_line_search": int(newton.line_search),
                "newton_tangent_every": newton.tangent_every,
                "newton_tangent_repair": newton.tangent_repair,
                "newton_predictor": newton.predictor,
                "newton_acceleration": newton.acceleration,
                **tangent_attrs,
                "gauss_points_per_element": per_element,
            },
        )
