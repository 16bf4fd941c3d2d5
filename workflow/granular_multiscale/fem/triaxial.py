"""Conventional triaxial test on a box-shaped specimen of trilinear hexahedra.

    problem = TriaxialProblem.from_config(config)
    problem.n_gauss_points, problem.gp_positions          # [n_gp, 3]; gp = element * 8 + q
    ds = problem.run(material, load_path, checkpoint=None, logger=None, progress=True)
    granular_multiscale.data.write_run(ds, path, config)

Boundary conditions (z is the axial direction, specimen [0, Lx]×[0, Ly]×[0, H]):

* bottom face: uz = 0; rough platen: also ux = uy = 0; smooth platen: only the node at
  the origin (ux = uy = 0) and the node at (Lx, 0, 0) (uy = 0) are pinned against rigid
  motion, so a homogeneous material deforms homogeneously;
* top face: uz = −axial_strain · H following the load path (axial strain compression
  positive); rough platen: also ux = uy = 0;
* four lateral faces: the constant confining pressure p0 as a traction −p0·n;
* the material points start from the consolidated stress −p0·1, which is in equilibrium
  with the confinement at zero displacement (step 0 solves and records this state).

Quarter symmetry (``specimen.symmetry: quarter``): only the quarter x ≥ Lx/2, y ≥ Ly/2 is
meshed, in the full specimen's coordinates (so Gauss-point and node positions compare
directly with a full run), with ceil(nx/2)×ceil(ny/2)×nz elements — exactly the full mesh's
elements there when nx and ny are even, 4× fewer Gauss points. The cut planes carry the
symmetry conditions u_x = 0 on x = Lx/2 and u_y = 0 on y = Ly/2; the confinement acts on
the two outer lateral faces; with smooth platens these conditions already remove the
rigid-body motions (no pins). ``top_force`` is reported for the FULL specimen (4 × the
quarter's reaction), and ``volumetric_strain`` is the quarter's, which equals the full
specimen's for a symmetric field. Valid when the specimen, its material and its loading
are symmetric about both planes (README, "Quarter symmetry").

Uniform field (``specimen.uniform_field: true``, smooth platens only): the run takes a
material set of ONE point (:attr:`TriaxialProblem.n_material_points`) and broadcasts its
answer (``materials.wrappers.UniformField``); a trial field that is not homogeneous stops the
run with an error naming the Gauss points. A set of all points is accepted too (with a
warning that it does the work of every point).

Tangent repair (``newton.tangent_repair``): the run wraps whatever material set it gets in
``materials.wrappers.TangentRepair``; the run file records the repaired tangents and per step
``tangent_non_spd_points`` / ``tangent_repaired_points``.

Recorded per step (data contract, see ``granular_multiscale.data``): strains, stresses,
tangents and history variables at the Gauss points, nodal displacements, axial strain,
top force (tension positive, = ∫σzz over the top face = the platen reaction), volumetric
strain, Newton iterations and residual norms, cutbacks, wall time, the load phase and
whatever the material's ``step_info()`` reports.
"""

from __future__ import annotations

import hashlib
import json
import logging
import time
from pathlib import Path

import numpy as np
import xarray as xr

from .. import checkpoint as checkpoints
from ..data import tangent_variables
from ..history import HIST, history_from_sequence
from ..materials.wrappers import TangentRepair, UniformField
from ..paths import LoadPath
from ..tensors import COMP, TCOMP, TCOMP36
from .assembly import POINTS_PER_ELEMENT, GaussPointOperators
from .mesh import box_mesh, face_nodes, lateral_facets
from .newton import (
    Converged,
    ConvergenceError,
    DirichletSystem,
    NewtonSettings,
    StepFailed,
    Timers,
    newton_solve,
)

CHECKPOINT_VERSION = 3
SYMMETRIES = ("none", "quarter")


def _cost_split(timers, total: float, resume_time: float = 0.0) -> dict:
    """Run-file attributes: the cost split of a run, complete or stopped early. A resumed run
    counts the load steps before and after its checkpoint (the timers travel with it); the
    resume itself (reloading and replaying the material state) is ``time_resume_s``, and the
    work lost with a killed step is counted nowhere."""
    return {
        "time_material_s": timers.material,
        "time_assembly_s": timers.assembly,
        "time_solve_s": timers.solve,
        "time_run_s": total,
        "time_resume_s": resume_time,
        "total_newton_corrections": timers.iterations,
        "total_material_evaluations": timers.evaluations,
        "total_tangent_evaluations": timers.tangent_evaluations,
        "total_line_search_cuts": timers.line_search_cuts,
    }


class TriaxialProblem:
    def __init__(
        self,
        size=(0.5, 0.5, 1.0),
        elements=(2, 2, 4),
        confining_pressure: float = 1.0e5,
        platen: str = "rough",
        newton: NewtonSettings | None = None,
        symmetry: str = "none",
        uniform_field: bool = False,
    ):
        if platen not in ("rough", "smooth"):
            raise ValueError(f"specimen.platen must be 'rough' or 'smooth', got {platen!r}")
        if not confining_pressure > 0:
            raise ValueError(f"specimen.confining_pressure must be > 0, got {confining_pressure}")
        if symmetry not in SYMMETRIES:
            raise ValueError(f"specimen.symmetry must be one of {SYMMETRIES}, got {symmetry!r}")
        if uniform_field and platen != "smooth":
            raise ValueError("config key 'specimen.uniform_field': a uniform field needs specimen.platen 'smooth' "
                             "(rough platens restrain the ends, so the field is never homogeneous)")
        self.size = tuple(float(v) for v in size)
        self.elements = tuple(int(v) for v in elements)
        self.confining_pressure = float(confining_pressure)
        self.platen = platen
        self.newton = newton or NewtonSettings()
        self.symmetry = symmetry
        self.uniform_field = bool(uniform_field)

        if symmetry == "quarter":
            # the quarter x >= Lx/2, y >= Ly/2, in the full specimen's coordinates
            model_size = (self.size[0] / 2, self.size[1] / 2, self.size[2])
            origin = (self.size[0] / 2, self.size[1] / 2, 0.0)
            self.mesh_elements = (-(-self.elements[0] // 2), -(-self.elements[1] // 2), self.elements[2])
            self.force_factor = 4.0
        else:
            model_size, origin = self.size, (0.0, 0.0, 0.0)
            self.mesh_elements = self.elements
            self.force_factor = 1.0
        self.mesh = box_mesh(model_size, self.mesh_elements, origin)
        self.ops = GaussPointOperators(self.mesh)
        self.faces = face_nodes(self.mesh, self.size)
        self.height = self.size[2]
        self.top_area = self.size[0] * self.size[1]
        self.volume = self.top_area * self.height
        loaded = ("xmax", "ymax") if symmetry == "quarter" else ("xmin", "xmax", "ymin", "ymax")
        self.f_ext = self.ops.pressure_load(lateral_facets(self.mesh, self.size, loaded), self.confining_pressure)

        dofs = self.ops.node_dofs
        bottom, top = self.faces["bottom"], self.faces["top"]
        fixed = [dofs(bottom, 2)]
        if platen == "rough":
            fixed += [dofs(bottom, 0), dofs(bottom, 1), dofs(top, 0), dofs(top, 1)]
        if symmetry == "quarter":
            fixed += [dofs(self.faces["xmin"], 0), dofs(self.faces["ymin"], 1)]  # the two cut planes
        elif platen == "smooth":
            origin = self._node_at((0.0, 0.0, 0.0))
            x_corner = self._node_at((self.size[0], 0.0, 0.0))
            fixed += [dofs(origin, 0), dofs(origin, 1), dofs(x_corner, 1)]
        self.fixed_dofs = np.unique(np.concatenate(fixed))
        self.top_dofs = dofs(top, 2)  # axial displacement prescribed by the load path
        self.system = DirichletSystem(self.ops, np.concatenate([self.fixed_dofs, self.top_dofs]))
        self._gp_positions = self.ops.gauss_point_positions()

    @classmethod
    def from_config(cls, config: dict) -> "TriaxialProblem":
        spec = config["specimen"]
        return cls(
            size=spec["size"],
            elements=spec["elements"],
            confining_pressure=spec["confining_pressure"],
            platen=spec["platen"],
            newton=NewtonSettings.from_config(config),
            symmetry=spec.get("symmetry", "none"),
            uniform_field=bool(spec.get("uniform_field", False)),
        )

    # -- geometry ---------------------------------------------------------------------
    def _node_at(self, x) -> np.ndarray:
        d = np.linalg.norm(self.mesh.p.T - np.asarray(x), axis=1)
        return np.array([int(np.argmin(d))])

    @property
    def n_gauss_points(self) -> int:
        return self.ops.n_gauss_points

    @property
    def n_elements(self) -> int:
        return self.ops.n_elements

    @property
    def n_material_points(self) -> int:
        """Points the material set must have: 1 with specimen.uniform_field, else one per Gauss point."""
        return 1 if self.uniform_field else self.n_gauss_points

    @property
    def gp_positions(self) -> np.ndarray:
        return self._gp_positions.copy()

    @property
    def node_positions(self) -> np.ndarray:
        return self.mesh.p.T.copy()

    @property
    def initial_stress(self) -> np.ndarray:
        """The consolidated isotropic state −p0·1 (Voigt) the material points start from."""
        return -self.confining_pressure * np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])

    def prescribed_values(self, axial_strain: float) -> np.ndarray:
        """Values of the constrained dofs (system order) at an axial strain (compression positive)."""
        values = np.zeros(self.system.constrained.size)
        values[np.isin(self.system.constrained, self.top_dofs)] = -axial_strain * self.height
        return values

    def top_force(self, residual: np.ndarray) -> float:
        """Platen reaction of the full specimen in N, tension positive: Σ over the top nodes of
        (f_int − f_ext)_z (× 4 with quarter symmetry)."""
        return self.force_factor * float(residual[self.top_dofs].sum())

    def volumetric_strain(self, strain: np.ndarray) -> float:
        """Volume change of the specimen / volume (tension positive), = mean trace of ε."""
        return float(self.ops.volume_average(strain[:, :3].sum(axis=1)))

    def signature(self, material, load_path: LoadPath) -> str:
        """Identifies a run (problem, path, material kind) so a checkpoint is only reused for the same run."""
        key = {
            "size": self.size,
            "elements": self.elements,
            "confining_pressure": self.confining_pressure,
            "platen": self.platen,
            "symmetry": self.symmetry,
            "uniform_field": self.uniform_field,
            "newton": self.newton.__dict__,
            "path": [load_path.name, [list(s) for s in load_path.segments]],
            "material": [getattr(material, "method", type(material).__name__), material.n_points],
            # what the material set's converged state depends on (DEM: packings and settings)
            "material_key": material.checkpoint_key(),
            "version": CHECKPOINT_VERSION,
        }
        return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()

    # -- solving ----------------------------------------------------------------------
    def _wrap(self, material, logger: logging.Logger):
        """The material set as the solver sees it: uniform-field broadcast and tangent repair as configured."""
        n = material.n_points
        if self.uniform_field and n == 1 and self.n_gauss_points > 1:
            if self.newton.tangent_repair != "none":  # repair the one point, then broadcast
                material = TangentRepair(material, self.newton.tangent_repair, self.newton.tangent_floor)
            return UniformField(material, self.n_gauss_points)
        if n != self.n_gauss_points:
            expected = "1 (specimen.uniform_field) or " if self.uniform_field else ""
            raise ValueError(
                f"material set has {n} points, the mesh {self.n_gauss_points} Gauss points (expected {expected}"
                f"{self.n_gauss_points})"
            )
        if self.uniform_field and n > 1:
            logger.warning("specimen.uniform_field is set but the material set has all %d points: every point is "
                           "evaluated (make it with problem.n_material_points = 1 point to save the work)", n)
        if self.newton.tangent_repair != "none":
            material = TangentRepair(material, self.newton.tangent_repair, self.newton.tangent_floor)
        return material

    def _solve_step(self, material, step: int, a_from: float, a_to: float, u: np.ndarray,
                    previous: Converged | None, timers: Timers):
        """Advance from axial strain a_from to a_to, halving on failure; commits every sub-step."""
        stats = {"cutbacks": 0, "iterations": 0}

        def advance(lo: float, hi: float, depth: int, u_start, prev):
            try:
                result = newton_solve(self.ops, self.system, material, self.f_ext, u_start,
                                      self.prescribed_values(hi), self.newton, prev, timers)
            except StepFailed as error:
                if hi == lo:  # no increment to halve (step 0, the consolidated state, or a hold)
                    raise ConvergenceError(
                        f"load step {step} (axial strain {a_from:.6g} -> {a_to:.6g}) did not converge, and a step "
                        f"without an axial strain increment cannot be cut back: {error}"
                    ) from error
                if depth >= self.newton.max_cutbacks:
                    raise ConvergenceError(
                        f"load step {step} (axial strain {a_from:.6g} -> {a_to:.6g}) did not converge after "
                        f"{depth} cutbacks (sub-step {lo:.6g} -> {hi:.6g}): {error}"
                    ) from error
                stats["cutbacks"] += 1
                mid = 0.5 * (lo + hi)
                half = advance(lo, mid, depth + 1, u_start, prev)
                return advance(mid, hi, depth + 1, half.u, half)
            material.commit(result.strain)  # the accepted state, whichever trial was evaluated last
            stats["iterations"] += result.iterations
            return result

        result = advance(a_from, a_to, 0, u, previous)
        return result, stats

    def run(self, material, load_path: LoadPath, method: str | None = None, checkpoint=None,
            logger: logging.Logger | None = None, progress: bool = True) -> xr.Dataset:
        """Run the load path; returns the data-contract Dataset (write it with data.write_run)."""
        logger = logger or logging.getLogger("granular_multiscale.fem")
        method = method or getattr(material, "method", "material")
        material_points = material.n_points  # before the uniform-field broadcast: what was evaluated
        material = self._wrap(material, logger)
        axial = load_path.axial_strain()
        phases = load_path.phase()
        signature = self.signature(material, load_path)
        checkpoint = Path(checkpoint) if checkpoint else None

        records: dict[str, list] = {k: [] for k in (
            "strain", "stress", "tangent", "displacement", "axial_strain", "top_force", "volumetric_strain",
            "newton_iterations", "material_evaluations", "tangent_evaluations", "residual_norm", "residual_reference", "cutbacks",
            "wall_time", "step_info")}
        u = np.zeros(self.ops.n_dofs)
        previous: Converged | None = None
        first = 0
        timers = Timers()
        elapsed_before = 0.0  # load-step time of the steps a resumed run takes from its checkpoint
        resume_time = 0.0
        t0 = time.perf_counter()
        saved = checkpoints.resume(checkpoint, signature, material, logger)
        if saved is not None:
            records, u, previous = saved["records"], saved["u"], saved["previous"]
            timers = Timers(**saved["timers"])
            elapsed_before = float(saved["elapsed"])
            first = saved["step"] + 1
            resume_time = time.perf_counter() - t0
            logger.info("resuming from checkpoint %s after step %d (%.1f s of load steps done; resume took "
                        "%.1f s)", checkpoint, saved["step"], elapsed_before, resume_time)

        t_run = time.perf_counter()

        def elapsed() -> float:
            """Load-step time of the whole run, across resumes (the resume itself excluded)."""
            return elapsed_before + time.perf_counter() - t_run
        for step in range(first, load_path.n_steps + 1):
            t0 = time.perf_counter()
            evaluations_before, tangents_before = timers.evaluations, timers.tangent_evaluations
            a_from = axial[step - 1] if step > 0 else 0.0
            try:
                result, stats = self._solve_step(material, step, a_from, axial[step], u, previous, timers)
            except ConvergenceError as error:
                if records["axial_strain"]:
                    error.partial = self._dataset(records, load_path, method, material_points)
                    error.partial.attrs.update({"stopped_at_step": step, "stop_reason": str(error),
                                                **_cost_split(timers, elapsed(), resume_time)})
                logger.error("%s", error)
                raise
            u, previous = result.u, result
            info = material.step_info() or {}
            wall = time.perf_counter() - t0

            records["strain"].append(result.strain)
            records["stress"].append(result.stress)
            records["tangent"].append(np.array(result.tangent, dtype=float))  # all 36 entries (data.tangent_variables)
            records["displacement"].append(self.ops.nodal(u))
            records["axial_strain"].append(axial[step])
            records["top_force"].append(self.top_force(result.residual))
            records["volumetric_strain"].append(self.volumetric_strain(result.strain))
            records["newton_iterations"].append(stats["iterations"])
            records["material_evaluations"].append(timers.evaluations - evaluations_before)
            records["tangent_evaluations"].append(timers.tangent_evaluations - tangents_before)
            records["residual_norm"].append(list(result.residual_norms))
            records["residual_reference"].append(result.reference)
            records["cutbacks"].append(stats["cutbacks"])
            records["wall_time"].append(wall)
            records["step_info"].append(dict(info))
            if checkpoint is not None:
                checkpoints.save(checkpoint, {
                    "signature": signature, "step": step, "records": records, "u": u,
                    "previous": previous, "material_state": material.get_state(),
                    "timers": timers.as_dict(), "elapsed": elapsed(),
                })
            if progress:
                logger.info(
                    "step %3d/%d %-9s axial strain %.4f %%  iterations %2d  residual %.2e  cutbacks %d  %.2f s",
                    step, load_path.n_steps, phases[step], 100 * axial[step], stats["iterations"],
                    result.residual_norms[-1] / result.reference, stats["cutbacks"], wall,
                )
        ds = self._dataset(records, load_path, method, material_points)
        ds.attrs.update(_cost_split(timers, elapsed(), resume_time))
        if checkpoint is not None:
            checkpoint.unlink(missing_ok=True)
        return ds

    # -- output -----------------------------------------------------------------------
    def _dataset(self, rec: dict, load_path: LoadPath, method: str, material_points: int) -> xr.Dataset:
        n_steps = len(rec["axial_strain"])
        strain = np.asarray(rec["strain"])
        longest = max(len(r) for r in rec["residual_norm"])
        residuals = np.full((n_steps, longest), np.nan)
        for k, r in enumerate(rec["residual_norm"]):
            residuals[k, : len(r)] = r
        step = np.arange(n_steps)
        repair = self.newton.tangent_repair
        tangent_vars, tangent_attrs = tangent_variables(rec["tangent"], (
            "as the material set returned it" if repair == "none" else
            f"after newton.tangent_repair '{repair}' (eigenvalue floor {self.newton.tangent_floor:g} x the largest): "
            "points whose tangent was repaired (tangent_repaired_points per step) hold the floored symmetric "
            "matrix, the others the material's own tangent"))
        coords = {
            "step": step,
            "gp": np.arange(self.n_gauss_points),
            "comp": list(COMP),
            "tcomp": list(TCOMP),
            **({"tcomp36": list(TCOMP36)} if "tangent_full" in tangent_vars else {}),
            "hist": list(HIST),
            "node": np.arange(self.mesh.p.shape[1]),
            "xyz": ["x", "y", "z"],
            "iteration": np.arange(longest),
        }
        v = {
            "strain": (("step", "gp", "comp"), strain, "1", "total small strain, tensorial shear, tension positive"),
            "stress": (("step", "gp", "comp"), np.asarray(rec["stress"]), "Pa", "Cauchy stress, tension positive"),
            **tangent_vars,  # tangent, and tangent_full when it is not symmetric
            "history": (("step", "gp", "hist"), history_from_sequence(strain), "1",
                        "history variables phi1-phi3, psi1, psi2 of the converged strains"),
            "gp_position": (("gp", "xyz"), self.gp_positions, "m", "Gauss point coordinates (gp = element*8 + q)"),
            "node_position": (("node", "xyz"), self.node_positions, "m", "node coordinates"),
            "displacement": (("step", "node", "xyz"), np.asarray(rec["displacement"]), "m", "nodal displacement"),
            "axial_strain": (("step",), np.asarray(rec["axial_strain"]), "1",
                             "prescribed axial strain, compression positive (top uz = -axial_strain * H)"),
            "top_force": (("step",), np.asarray(rec["top_force"]), "N",
                          "axial platen reaction of the full specimen, tension positive (= integral of sigma_zz "
                          "over the top face)" + ("; quarter symmetry: 4 x the modelled quarter's reaction"
                                                  if self.symmetry == "quarter" else "")),
            "volumetric_strain": (("step",), np.asarray(rec["volumetric_strain"]), "1",
                                  "volume change / volume of the specimen, tension positive"),
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
                "load_path": load_path.name,
                "load_path_segments": json.dumps([list(s) for s in load_path.segments]),
                "specimen_size_m": list(self.size),
                "specimen_elements": list(self.elements),
                "confining_pressure_Pa": self.confining_pressure,
                "platen": self.platen,
                "symmetry": self.symmetry,
                "modelled_fraction": 1.0 / self.force_factor,
                "mesh_elements": list(self.mesh_elements),
                "uniform_field": int(self.uniform_field),
                "material_points": int(material_points),
                "newton_tolerance": self.newton.tolerance,
                "newton_line_search": int(self.newton.line_search),
                "newton_tangent_every": self.newton.tangent_every,
                "newton_tangent_repair": self.newton.tangent_repair,
                "newton_predictor": self.newton.predictor,
                "newton_acceleration": self.newton.acceleration,
                **tangent_attrs,
                "gauss_points_per_element": POINTS_PER_ELEMENT,
            },
        )
