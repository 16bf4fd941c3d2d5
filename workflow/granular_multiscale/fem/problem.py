"""The base of every boundary-value problem: mesh and Gauss points, boundary conditions, load
control, the step loop with cutbacks, the checkpoint and the recording of the data contract.

    problem = make_problem(config, "biaxial")            # fem/__init__.py: by name, from the config
    problem.n_material_points, problem.gp_positions      # what the material set must provide
    ds = problem.run(material, load_path, checkpoint=None, logger=None, progress=True)

A problem (``triaxial.py``, ``biaxial.py``, ``footing.py``) adds only its mesh, its boundary
conditions and its observables; it calls :meth:`BoundaryValueProblem._set_up` with

* the Gauss-point operators (``assembly.GaussPointOperators``: hexahedra, or quadrilaterals in
  plane strain),
* the constant external load ``f_ext`` (confining pressure, surcharge),
* the fixed dofs (zero displacement) and the loaded dofs, which the load path moves: at load
  λ (the path's value: axial strain, settlement / footing width) their displacement is
  −λ · ``load_length`` (downwards),

and it names what it reports: :attr:`OBSERVABLES` per step, :meth:`attributes` per run.

Load control. A load step moves λ from the last converged value to the path's next value
with Newton (``newton.newton_solve``); a step that does not converge is halved, up to
``newton.max_cutbacks`` times, every accepted sub-step committed; one that still fails stops
the run with :class:`~.newton.ConvergenceError` naming the step, whose ``partial`` holds the
converged steps (never written as the run's output).

Checkpoint: after every load step, {signature, step, records, u, previous, material state,
timers, elapsed} is pickled atomically (``granular_multiscale.checkpoint``); a run started again
with the same signature (problem, path, material kind and its ``checkpoint_key``, Newton
settings) resumes after the last step done, bit for bit for materials that replay exactly.

The problem never learns what sits at its Gauss points: the material set is whatever the
driver passes, wrapped only in the uniform-field broadcast and the tangent repair the config
asks for (:meth:`_wrap`).
"""

from __future__ import annotations

import hashlib
import json
import logging
import time
from pathlib import Path

import numpy as np
import xarray as xr

from .. import checkpoint as checkpoints, integrity
from ..materials.wrappers import TangentRepair, UniformField
from ..paths import LoadPath
from ..tensors import isotropic_elastic_tangent
from .assembly import GaussPointOperators
from .newton import Converged, ConvergenceError, DirichletSystem, NewtonSettings, StepFailed, Timers, newton_solve
from .recorder import RunRecorder

CHECKPOINT_VERSION = 4


def cost_split(timers: Timers, total: float, resume_time: float = 0.0) -> dict:
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


class BoundaryValueProblem:
    """Mesh, boundary conditions, load control and step loop shared by every problem."""

    #: name in the config and the run files (attribute ``problem``)
    name = "problem"
    #: the config section of the problem (error messages name its keys)
    config_section = "problem"
    #: what the load path's values λ are, in logs and error messages ("axial strain")
    load_label = "load"
    #: the same for the run file's ``load_measure`` attribute
    load_measure = "load"
    #: where the load acts (run-file descriptions)
    loaded_boundary = "loaded boundary"
    #: the body (run-file descriptions)
    domain_name = "domain"
    #: name -> (units, description) of the per-step values :meth:`observables` returns
    OBSERVABLES: dict[str, tuple[str, str]] = {}

    # -- set-up by the subclass -------------------------------------------------------------
    def _set_up(self, ops: GaussPointOperators, f_ext: np.ndarray, fixed_dofs, loaded_dofs: np.ndarray,
                load_length: float, confining_pressure: float, newton: NewtonSettings | None,
                uniform_field: bool = False, force_factor: float = 1.0) -> None:
        self.ops = ops
        self.mesh = ops.mesh
        self.f_ext = f_ext
        self.fixed_dofs = np.unique(np.concatenate(fixed_dofs))
        self.loaded_dofs = np.asarray(loaded_dofs)
        self.load_length = float(load_length)
        self.confining_pressure = float(confining_pressure)
        self.newton = newton or NewtonSettings()
        self.uniform_field = bool(uniform_field)
        self.force_factor = float(force_factor)
        self.system = DirichletSystem(ops, np.concatenate([self.fixed_dofs, self.loaded_dofs]))
        self._gp_positions = ops.gauss_point_positions()
        self._virtual_load_field: np.ndarray | None = None  # load_force_in_virtual_work builds it once

    # -- what a subclass says about itself ----------------------------------------------------
    def definition(self) -> dict:
        """What defines the problem (geometry, mesh, boundary conditions): part of the checkpoint signature."""
        raise NotImplementedError

    def attributes(self) -> dict:
        """Run-file attributes of the problem (geometry, mesh, conventions)."""
        return {}

    def observables(self, load: float, result: Converged) -> dict[str, float]:
        """Per-step values of :attr:`OBSERVABLES` at a converged state."""
        return {}

    def force_observables(self, load_force: float) -> dict[str, float]:
        """Those of :meth:`observables` that follow from the load force (top_force, footing_pressure)."""
        return {}

    def observable_meanings(self) -> dict[str, tuple[str, str]]:
        """(units, description) of each per-step value :meth:`observables` returns."""
        return dict(self.OBSERVABLES)

    def load_force_meaning(self) -> dict[str, str]:
        """Units and description of the run file's ``load_force``."""
        return {"units": "N", "description": f"reaction of the {self.loaded_boundary} along the load, "
                                             "positive in compression"}

    # -- geometry -----------------------------------------------------------------------------
    @property
    def n_gauss_points(self) -> int:
        return self.ops.n_gauss_points

    @property
    def n_elements(self) -> int:
        return self.ops.n_elements

    @property
    def n_material_points(self) -> int:
        """Points the material set must have: 1 with a uniform field, else one per Gauss point."""
        return 1 if self.uniform_field else self.n_gauss_points

    @property
    def gp_positions(self) -> np.ndarray:
        return self._gp_positions.copy()

    @property
    def node_positions(self) -> np.ndarray:
        return self.ops.node_positions

    @property
    def initial_stress(self) -> np.ndarray:
        """The consolidated isotropic state −p0·1 (Voigt) the material points start from."""
        return -self.confining_pressure * np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])

    def _node_at(self, x) -> np.ndarray:
        d = np.linalg.norm(self.ops.mesh_node_positions - np.asarray(x, dtype=float), axis=1)
        return np.array([int(np.argmin(d))])

    # -- load control and what is measured -----------------------------------------------------
    def prescribed_values(self, load: float) -> np.ndarray:
        """Values of the constrained dofs (system order) at load λ: the loaded dofs at −λ·load_length."""
        values = np.zeros(self.system.constrained.size)
        values[np.isin(self.system.constrained, self.loaded_dofs)] = -load * self.load_length
        return values

    def load_force(self, residual: np.ndarray) -> float:
        """Reaction of the loaded boundary along the load, compression positive: −Σ (f_int − f_ext)
        over the loaded dofs, for the whole body (× ``force_factor`` with a symmetry reduction)."""
        return -self.force_factor * float(residual[self.loaded_dofs].sum())

    def load_force_in_virtual_work(self, stress: np.ndarray) -> float:
        """The load force (as :meth:`load_force`) that Gauss-point stresses [n_gp, 6] carry in virtual
        work: −v·(f_int(σ) − f_ext) with the virtual displacement v of :meth:`virtual_load_field`.

        For stresses in equilibrium (a converged state) it is the reaction itself, whatever v: the
        residual vanishes at the free dofs and v is 1 at the loaded dofs, 0 at the fixed ones. For
        stresses that are not (a material driven along another run's strains, with no FEM) the
        reaction at the loaded dofs alone would weigh only the elements that touch them; v weighs
        every point by how much a load of the boundary strains it."""
        if self._virtual_load_field is None:
            self._virtual_load_field = self.virtual_load_field()
        residual = self.ops.internal_force(stress) - self.f_ext
        return -self.force_factor * float(self._virtual_load_field @ residual)

    def virtual_load_field(self) -> np.ndarray:
        """[n_dofs] the displacement of an isotropic linear elastic body (ν = 0.3) whose loaded dofs
        move by 1 along the load, the fixed ones not at all (the problem's boundary conditions)."""
        elastic = isotropic_elastic_tangent(1.0, 0.3)
        K = self.ops.stiffness_data(np.broadcast_to(elastic, (self.n_gauss_points, 6, 6)))
        prescribed = np.zeros(self.ops.n_dofs)
        prescribed[self.system.constrained] = self.prescribed_values(1.0)
        u = prescribed + self.system.solve(K, -(self.ops.csr(K) @ prescribed))
        return u / -self.load_length  # prescribed_values(1.0) moves the loaded dofs by −load_length

    def volumetric_strain(self, strain: np.ndarray) -> float:
        """Volume change / volume (tension positive), = mean trace of ε (area change in plane strain)."""
        return float(self.ops.volume_average(strain[:, :3].sum(axis=1)))

    def zones(self) -> np.ndarray:
        """[n_material_points] material zone of each point (0 everywhere; a problem with a weak zone: 1 there)."""
        return np.zeros(self.n_material_points, dtype=int)

    def check_load_path(self, load_path: LoadPath) -> None:
        """Refuse a load path this problem cannot follow (ValueError naming the config key)."""

    def signature(self, material, load_path: LoadPath) -> str:
        """Identifies a run (problem, path, material kind) so a checkpoint is only reused for the same run."""
        key = {
            **self.definition(),
            "newton": self.newton.__dict__,
            "path": [load_path.name, [list(s) for s in load_path.segments]],
            "material": [getattr(material, "method", type(material).__name__), material.n_points],
            # what the material set's converged state depends on (DEM: packings and settings)
            "material_key": material.checkpoint_key(),
            "version": CHECKPOINT_VERSION,
        }
        return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()

    # -- solving --------------------------------------------------------------------------------
    def _wrap(self, material, logger: logging.Logger):
        """The material set as the solver sees it: uniform-field broadcast and tangent repair as configured."""
        n = material.n_points
        key = f"{self.config_section}.uniform_field"
        if self.uniform_field and n == 1 and self.n_gauss_points > 1:
            if self.newton.tangent_repair != "none":  # repair the one point, then broadcast
                material = TangentRepair(material, self.newton.tangent_repair, self.newton.tangent_floor)
            return UniformField(material, self.n_gauss_points)
        if n != self.n_gauss_points:
            expected = f"1 ({key}) or " if self.uniform_field else ""
            raise ValueError(
                f"material set has {n} points, the mesh {self.n_gauss_points} Gauss points (expected {expected}"
                f"{self.n_gauss_points})"
            )
        if self.uniform_field and n > 1:
            logger.warning("%s is set but the material set has all %d points: every point is "
                           "evaluated (make it with problem.n_material_points = 1 point to save the work)", key, n)
        if self.newton.tangent_repair != "none":
            material = TangentRepair(material, self.newton.tangent_repair, self.newton.tangent_floor)
        return material

    def _solve_step(self, material, step: int, a_from: float, a_to: float, u: np.ndarray,
                    previous: Converged | None, timers: Timers):
        """Advance from load a_from to a_to, halving on failure; commits every sub-step."""
        stats = {"cutbacks": 0, "iterations": 0}
        what = self.load_label

        def advance(lo: float, hi: float, depth: int, u_start, prev):
            try:
                result = newton_solve(self.ops, self.system, material, self.f_ext, u_start,
                                      self.prescribed_values(hi), self.newton, prev, timers)
            except StepFailed as error:
                if hi == lo:  # no increment to halve (step 0, the consolidated state, or a hold)
                    raise ConvergenceError(
                        f"load step {step} ({what} {a_from:.6g} -> {a_to:.6g}) did not converge, and a step "
                        f"without an {what} increment cannot be cut back: {error}"
                    ) from error
                if depth >= self.newton.max_cutbacks:
                    raise ConvergenceError(
                        f"load step {step} ({what} {a_from:.6g} -> {a_to:.6g}) did not converge after "
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
        self.check_load_path(load_path)
        method = method or getattr(material, "method", "material")
        material_points = material.n_points  # before the uniform-field broadcast: what was evaluated
        material = self._wrap(material, logger)
        loads = load_path.axial_strain()
        phases = load_path.phase()
        signature = self.signature(material, load_path)
        checkpoint = Path(checkpoint) if checkpoint else None

        recorder = RunRecorder()
        u = np.zeros(self.ops.n_dofs)
        previous: Converged | None = None
        first = 0
        timers = Timers()
        elapsed_before = 0.0  # load-step time of the steps a resumed run takes from its checkpoint
        resume_time = 0.0
        t0 = time.perf_counter()
        saved = checkpoints.resume(checkpoint, signature, material, logger)
        if saved is not None:
            recorder = RunRecorder(saved["records"])
            u, previous = saved["u"], saved["previous"]
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
            a_from = loads[step - 1] if step > 0 else 0.0
            try:
                result, stats = self._solve_step(material, step, a_from, loads[step], u, previous, timers)
            except ConvergenceError as error:
                if recorder.n_steps:
                    error.partial = recorder.dataset(self, load_path, method, material_points)
                    error.partial.attrs.update({"stopped_at_step": step, "stop_reason": str(error),
                                                **cost_split(timers, elapsed(), resume_time)})
                logger.error("%s", error)
                raise
            u, previous = result.u, result
            info = material.step_info() or {}
            wall = time.perf_counter() - t0
            recorder.record(
                result=result, load=loads[step], load_force=self.load_force(result.residual),
                volumetric_strain=self.volumetric_strain(result.strain), displacement=self.ops.nodal(u),
                iterations=stats["iterations"], evaluations=timers.evaluations - evaluations_before,
                tangent_evaluations=timers.tangent_evaluations - tangents_before, cutbacks=stats["cutbacks"],
                wall=wall, step_info=info, observables=self.observables(loads[step], result),
            )
            if checkpoint is not None:
                checkpoints.save(checkpoint, {
                    "signature": signature, "step": step, "records": recorder.records, "u": u,
                    "previous": previous, "material_state": material.get_state(),
                    "timers": timers.as_dict(), "elapsed": elapsed(),
                })
            if progress:
                logger.info(
                    "step %3d/%d %-9s %s %.4f %%  iterations %2d  residual %.2e  cutbacks %d  %.2f s",
                    step, load_path.n_steps, phases[step], self.load_label, 100 * loads[step],
                    stats["iterations"], result.residual_norms[-1] / result.reference, stats["cutbacks"], wall,
                )
        # the run's time is that of its load steps: taken before the run file's Dataset is built,
        # whose first xarray Variable of a process imports dask (0.45 s, half of a FEM–ML run)
        total = elapsed()
        ds = recorder.dataset(self, load_path, method, material_points)
        ds.attrs.update(cost_split(timers, total, resume_time))
        if checkpoint is not None:
            integrity.forget(checkpoint)
        return ds
