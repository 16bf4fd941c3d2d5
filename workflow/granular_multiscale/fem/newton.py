"""Newton–Raphson for a displacement-driven quasi-static step, with cutbacks.

Residual R(u) = f_int(σ(ε(u))) − f_ext. Prescribed (Dirichlet) dofs take their target
values; free dofs are corrected with the tangent stiffness assembled from the material
set's tangent until

    ‖R_free‖ ≤ tolerance · max(‖f_ext‖, ‖R_constrained‖, 1 N)

(‖R_constrained‖ is the reaction). Each step starts with a predictor that uses the
stiffness of the last converged state: free dofs follow the prescribed increment as
K_ff δu_f = −(R_f + K_fc Δu_c). It costs one solve and no material evaluation, and for the
expensive material sets (DEM) saves one evaluation per step compared with a step that
only moves the boundary nodes and lets the first iteration sort the interior out.
With ``predictor: extrapolate`` a step whose prescribed increment continues the last one
(same sign) starts instead from the last converged increment scaled to this one,
u₀ = u_n + r (u_n − u_{n−1}): no solve, and on a path of equal increments the interior is
where the last step put it; at a reversal (r ≤ 0) the tangent predictor is used.

The material set is evaluated from its converged state at every iteration (evaluate is
repeatable) and committed only after convergence, so a failed attempt leaves it untouched
and a cutback simply starts again from the same converged state.

Options (config section ``newton``):

* ``line_search``: backtracking on the residual norm. The full step is tried first and
  kept when ‖R_free‖ drops by the Armijo factor (1 − 10⁻⁴ α); otherwise α is halved up to
  ``line_search_max`` times. The evaluation at the accepted step is the next iteration's,
  so an accepted full step costs nothing extra. A trial the material refuses
  (MaterialPointError, e.g. a point beyond the cone apex) counts as a rejected length
  instead of failing the attempt.
* ``tangent_every`` = k > 1: modified Newton. The stiffness is reassembled only at
  iterations k, 2k, …; iteration 0 reuses the stiffness of the last converged state (the
  predictor's). Evaluations in between call ``evaluate(strain, need_tangent=False)``, so a
  material whose tangent is expensive (autodiff surrogate) is not asked for it. The tangent
  of the converged state is always obtained (one extra evaluation when the converged
  iteration did not ask for it): the run file records it and the next step's predictor uses it.
* ``acceleration: anderson``: Anderson acceleration (depth ``anderson_depth``) of the
  corrections. With an inexact tangent (DEM contact stiffness, a learned ND tangent, modified
  Newton) Newton is the fixed-point iteration u ← u + δu(u), δu = −K⁻¹R(u), which converges
  only linearly; Anderson mixing combines the last m iterates and corrections,

      γ = argmin ‖δu_k − ΔF γ‖,   u_{k+1} = u_k + δu_k − (ΔU + ΔF) γ

  (ΔU, ΔF: differences of successive iterates and corrections on the free dofs), at the cost
  of a small least-squares problem per iteration and no extra material evaluation. On Path2
  (2×2×4, elastoplastic) with the elastic instead of the consistent tangent it cuts the
  corrections from 1448 to 450; with the consistent tangent it changes little (79 -> 82).
  It cannot help a tangent that is drawn afresh at every evaluation (noisy tangent).
"""


from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse.linalg as spla

from ..materials.base import MaterialPointError
from .assembly import GaussPointOperators


PREDICTORS = ("tangent", "extrapolate")


@dataclass(frozen=True)
class NewtonSettings:
    tolerance: float = 1e-8
    max_iterations: int = 25
    max_cutbacks: int = 4
    line_search: bool = False
    line_search_max: int = 5
    tangent_every: int = 1
    acceleration: str = "none"
    anderson_depth: int = 5
    tangent_repair: str = "none"
    tangent_floor: float = 1e-3
    predictor: str = "tangent"

    def __post_init__(self):
        checks = {
            "tolerance": self.tolerance > 0,
            "max_iterations": self.max_iterations >= 1,
            "max_cutbacks": self.max_cutbacks >= 0,
            "line_search_max": self.line_search_max >= 1,
            "tangent_every": self.tangent_every >= 1,
            "acceleration": self.acceleration in ("none", "anderson"),
            "anderson_depth": self.anderson_depth >= 1,
            "tangent_repair": self.tangent_repair in ("none", "eig_floor"),
            "tangent_floor": 0 < self.tangent_floor < 1,
            "predictor": self.predictor in PREDICTORS,
        }
        for key, ok in checks.items():
            if not ok:
                raise ValueError(f"config key 'newton.{key}': invalid value {getattr(self, key)!r} (see the config schema)")

    @classmethod
    def from_config(cls, config: dict) -> "NewtonSettings":
        section = config["newton"]
        defaults = cls()
        return cls(
            tolerance=float(section["tolerance"]),
            max_iterations=int(section["max_iterations"]),
            max_cutbacks=int(section["max_cutbacks"]),
            line_search=bool(section.get("line_search", defaults.line_search)),
            line_search_max=int(section.get("line_search_max", defaults.line_search_max)),
            tangent_every=int(section.get("tangent_every", defaults.tangent_every)),
            acceleration=str(section.get("acceleration", defaults.acceleration)),
            anderson_depth=int(section.get("anderson_depth", defaults.anderson_depth)),
            tangent_repair=str(section.get("tangent_repair", defaults.tangent_repair)),
            tangent_floor=float(section.get("tangent_floor", defaults.tangent_floor)),
            predictor=str(section.get("predictor", defaults.predictor)),
        )


class StepFailed(RuntimeError):
    """One Newton attempt did not converge (internal: triggers a cutback)."""


class ConvergenceError(RuntimeError):
    """A load step did not converge after all cutbacks; the message names the step.

    Raised by ``TriaxialProblem.run`` with ``partial``: the run Dataset of the steps that did
    converge (attrs ``stopped_at_step`` and ``stop_reason``), for diagnosis — never written as
    the run's output."""

    partial = None


@dataclass
class Timers:
    material: float = 0.0
    assembly: float = 0.0
    solve: float = 0.0
    iterations: int = 0  # Newton corrections (linear solves after the predictor)
    evaluations: int = 0  # material evaluations, failed attempts included
    tangent_evaluations: int = 0  # evaluations that asked the material for its tangent
    line_search_cuts: int = 0  # step lengths rejected by the line search

    def as_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class Converged:
    """A converged state: displacement, Gauss-point strain/stress/tangent, residual vector."""

    u: np.ndarray
    strain: np.ndarray
    stress: np.ndarray
    tangent: np.ndarray
    residual: np.ndarray
    residual_norms: list = field(default_factory=list)
    reference: float = 1.0
    increment: np.ndarray | None = None  # u − u at the start of the solve that reached this state

    @property
    def iterations(self) -> int:
        return len(self.residual_norms) - 1


class DirichletSystem:
    """Linear solves on the free dofs of K with rows/columns of prescribed dofs eliminated.

    The masks over the fixed CSR pattern are built once; per solve the prescribed rows and
    columns are zeroed and their diagonal set to one (the right-hand side is zero there)."""

    def __init__(self, ops: GaussPointOperators, constrained: np.ndarray):
        self.ops = ops
        self.constrained = np.unique(constrained)
        self.free = np.setdiff1d(np.arange(ops.n_dofs), self.constrained)
        self._touching, self._diagonal = ops.entries_touching(self.constrained)

    def solve(self, K_data: np.ndarray, rhs: np.ndarray) -> np.ndarray:
        data = K_data.copy()
        data[self._touching] = 0.0
        data[self._diagonal] = 1.0
        b = rhs.copy()
        b[self.constrained] = 0.0
        # SuperLU with a minimum-degree ordering of AᵀA+A (K is structurally symmetric):
        # about 10–15 ms at the paper mesh (1188 dofs), the largest share of an iteration.
        return spla.spsolve(self.ops.csr(data).tocsc(), b, permc_spec="MMD_AT_PLUS_A")


@dataclass
class _Trial:
    """One material evaluation at displacement u and the residual it gives."""

    u: np.ndarray
    strain: np.ndarray
    stress: np.ndarray
    tangent: np.ndarray | None
    residual: np.ndarray
    norm: float
    reference: float


def _evaluate(ops, system, material, f_ext, u, need_tangent: bool, timers: Timers, iteration: int) -> _Trial:
    t0 = time.perf_counter()
    strain = ops.strain(u)
    t1 = time.perf_counter()
    timers.evaluations += 1
    timers.tangent_evaluations += int(need_tangent)
    try:
        stress, tangent = material.evaluate(strain, need_tangent=need_tangent)
    except MaterialPointError as error:
        raise StepFailed(f"material failed at iteration {iteration}: {error}") from error
    t2 = time.perf_counter()
    residual = ops.internal_force(stress) - f_ext
    t3 = time.perf_counter()
    timers.material += t2 - t1
    timers.assembly += (t1 - t0) + (t3 - t2)
    if need_tangent and tangent is None:
        raise TypeError(f"{type(material).__name__}.evaluate(need_tangent=True) returned no tangent")
    c, free = system.constrained, system.free
    norm = float(np.linalg.norm(residual[free]))
    reference = max(float(np.linalg.norm(f_ext)), float(np.linalg.norm(residual[c])), 1.0)
    return _Trial(u, strain, stress, tangent, residual, norm, reference)


def _line_search(ops, system, material, f_ext, u, du, current: _Trial, need_tangent: bool,
                 settings: NewtonSettings, timers: Timers, iteration: int) -> _Trial:
    """Backtracking along du: the first length with sufficient decrease of ‖R_free‖, else the best tried."""
    alpha, best, failure = 1.0, None, None
    for _ in range(settings.line_search_max + 1):
        try:
            trial = _evaluate(ops, system, material, f_ext, u + alpha * du, need_tangent, timers, iteration)
        except StepFailed as error:
            trial, failure = None, error
        if trial is not None and np.isfinite(trial.norm):
            if trial.norm <= (1.0 - 1e-4 * alpha) * current.norm:
                return trial
            if best is None or trial.norm < best.norm:
                best = trial
        timers.line_search_cuts += 1
        alpha *= 0.5
    if best is None:
        raise StepFailed(f"line search: no admissible step length at iteration {iteration} ({failure})")
    return best


class _Anderson:
    """Anderson mixing of the Newton corrections on the free dofs (type II, Walker & Ni 2011)."""

    def __init__(self, free: np.ndarray, depth: int):
        self.free, self.depth = free, depth
        self.u: list[np.ndarray] = []
        self.f: list[np.ndarray] = []

    def step(self, u: np.ndarray, du: np.ndarray) -> np.ndarray:
        """The mixed correction to add to u, given the plain correction du at u."""
        x, f = u[self.free], du[self.free]
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(f))):
            raise StepFailed("non-finite Newton correction (singular or non-finite tangent)")
        self.u.append(x.copy())
        self.f.append(f.copy())
        if len(self.u) > self.depth + 1:
            self.u.pop(0)
            self.f.pop(0)
        if len(self.u) < 2:
            return du
        dU = np.diff(np.asarray(self.u), axis=0).T  # [n_free, m]
        dF = np.diff(np.asarray(self.f), axis=0).T
        try:
            gamma, *_ = np.linalg.lstsq(dF, f, rcond=1e-10)
        except np.linalg.LinAlgError:
            # degenerate history (e.g. corrections of wildly different size): restart from this iterate
            self.u, self.f = self.u[-1:], self.f[-1:]
            return du
        mixed = du.copy()
        mixed[self.free] = f - (dU + dF) @ gamma
        return mixed


def _extrapolation_ratio(du_prescribed: np.ndarray, previous: Converged | None, constrained: np.ndarray) -> float:
    """Scale of the last converged increment that matches this step's prescribed increment (least
    squares on the prescribed dofs); 0 when there is none or the load reverses (a reversal
    unloads along a stiffer branch than the last increment shows: the tangent predictor then)."""
    if previous is None or previous.increment is None:
        return 0.0
    last = previous.increment[constrained]
    norm2 = float(last @ last)
    return float(du_prescribed @ last) / norm2 if norm2 > 0 else 0.0


def newton_solve(
    ops: GaussPointOperators,
    system: DirichletSystem,
    material,
    f_ext: np.ndarray,
    u_start: np.ndarray,
    u_constrained: np.ndarray,
    settings: NewtonSettings,
    previous: Converged | None,
    timers: Timers,
) -> Converged:
    """Newton from the converged `u_start` to prescribed values `u_constrained`; raises StepFailed."""
    c = system.constrained
    u = u_start.copy()
    du_c = np.zeros_like(u)
    du_c[c] = u_constrained - u_start[c]
    u += du_c
    K_data = None  # stiffness used for the corrections (refreshed on schedule)
    moves = bool(np.any(du_c[c] != 0))
    ratio = _extrapolation_ratio(du_c[c], previous, c) if settings.predictor == "extrapolate" and moves else 0.0
    if ratio > 0:
        # the last converged increment, scaled to this one: free of cost and, on a smooth path of
        # equal increments, much closer than the tangent predictor (the tangent ignores sliding)
        free = system.free
        u[free] += ratio * previous.increment[free]
    if previous is not None and ((moves and ratio <= 0) or settings.tangent_every > 1):
        t0 = time.perf_counter()
        K_prev = ops.stiffness_data(previous.tangent)
        t1 = time.perf_counter()
        timers.assembly += t1 - t0
        if moves and ratio <= 0:
            u += system.solve(K_prev, -(previous.residual + ops.csr(K_prev) @ du_c))
            timers.solve += time.perf_counter() - t1
        if settings.tangent_every > 1:
            K_data = K_prev

    def wants_tangent(iteration: int) -> bool:
        # full Newton: always; modified Newton: every k-th iteration, or when no stiffness exists yet
        return iteration % settings.tangent_every == 0 and (iteration > 0 or K_data is None)

    current = _evaluate(ops, system, material, f_ext, u, wants_tangent(0), timers, 0)
    anderson = _Anderson(system.free, settings.anderson_depth) if settings.acceleration == "anderson" else None
    norms: list[float] = []
    for iteration in range(settings.max_iterations + 1):
        norms.append(current.norm)
        if not np.isfinite(current.norm):
            raise StepFailed(f"non-finite residual at iteration {iteration}")
        if current.norm <= settings.tolerance * current.reference:
            if current.tangent is None:
                # the converged state's tangent: recorded in the run file and used by the next predictor
                current = _evaluate(ops, system, material, f_ext, current.u, True, timers, iteration)
            return Converged(current.u, current.strain, current.stress, current.tangent, current.residual, norms,
                             current.reference, current.u - u_start)
        if iteration == settings.max_iterations:
            break
        t0 = time.perf_counter()
        if current.tangent is not None and (K_data is None or wants_tangent(iteration)):
            K_data = ops.stiffness_data(current.tangent)
        t1 = time.perf_counter()
        du = system.solve(K_data, -current.residual)
        t2 = time.perf_counter()
        timers.assembly += t1 - t0
        timers.solve += t2 - t1
        timers.iterations += 1
        if anderson is not None:
            du = anderson.step(current.u, du)
        if settings.line_search:
            current = _line_search(ops, system, material, f_ext, current.u, du, current, wants_tangent(iteration + 1),
                                   settings, timers, iteration + 1)
        else:
            current = _evaluate(ops, system, material, f_ext, current.u + du, wants_tangent(iteration + 1), timers,
                                iteration + 1)
    raise StepFailed(
        f"no convergence in {settings.max_iterations} iterations "
        f"(relative residual {norms[-1] / current.reference:.3e} > {settings.tolerance:.1e})"
    )
