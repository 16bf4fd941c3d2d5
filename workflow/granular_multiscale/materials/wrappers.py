"""Wrappers around any material-point set (analytic, DEM, surrogate): they change what the
solver sees, never the solver.

* :class:`TangentRepair` — tangents that are not positive definite (a learned ND tangent, a
  noisy DEM contact tangent) replaced by the nearest symmetric matrix whose eigenvalues are
  at least a floor; counts per step how many raw tangents were not positive definite.
* :class:`NoisyTangent` — a DEM-like random perturbation of the tangent (stress untouched),
  seeded and a pure function of the trial strain, for robustness tests of the solver.
* :class:`Zoned` — a heterogeneous body of analytic materials: the points of each zone (a weak
  zone that triggers a shear band) answered by a material set of their own;
  :class:`ZonedSurrogate` the same for networks (FEM–ML's weak zone with networks of its own);
* :class:`UniformField` — a homogeneous scene (smooth platens, uniform material): one
  material point is evaluated and its answer broadcast to every Gauss point; a trial field
  that is not uniform stops the run with :class:`NonUniformFieldError`;
* :class:`IsotropicPrestrain` — a set consolidated at one pressure (networks trained on RVEs
  at p0) taken by an isotropic strain to another confining pressure before the solver starts,
  the solver's strain measured from there;

and the diagnostics :func:`non_spd_mask`, :func:`non_spd_share`, :func:`non_spd_per_step`.

Positive definiteness of a Voigt tangent D (acting on the engineering strain) is judged on
its Mandel form M = S D S, S = diag(1, 1, 1, √2, √2, √2): a congruence, so M and D are
definite together, and M's eigenvalues are those of the fourth-order tangent (the
engineering/tensorial factors of the Voigt form would otherwise weight shear and normal
directions differently). A non-symmetric D is positive definite when its symmetric part is.
"""

from __future__ import annotations

import logging
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from ..tensors import tangent_from_upper
from .base import MaterialPointError, MaterialPointSet

_S = np.array([1.0, 1.0, 1.0, np.sqrt(2.0), np.sqrt(2.0), np.sqrt(2.0)])
_ONE = np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])
REPAIRS = ("none", "eig_floor")


class NonUniformFieldError(RuntimeError):
    """A uniform-field material set received different trial strains at different Gauss points."""


# -- tangent diagnostics and repair ---------------------------------------------------------
def _mandel(D: np.ndarray) -> np.ndarray:
    sym = 0.5 * (D + np.swapaxes(D, -1, -2))
    return sym * _S[:, None] * _S[None, :]


def tangent_eigenvalues(D: np.ndarray) -> np.ndarray:
    """[..., 6, 6] Voigt tangents -> [..., 6] ascending eigenvalues of their symmetric Mandel form (Pa)."""
    return np.linalg.eigvalsh(_mandel(np.asarray(D, dtype=float)))


def non_spd_mask(D: np.ndarray) -> np.ndarray:
    """[..., 6, 6] -> [...] True where the tangent is not positive definite (smallest eigenvalue <= 0)."""
    return tangent_eigenvalues(D)[..., 0] <= 0.0


def eig_floor(D: np.ndarray, floor: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """Repair [n, 6, 6] tangents whose smallest eigenvalue is below `floor` × their largest |eigenvalue|.

    Those points get the symmetric part with the eigenvalues raised to the floor (the nearest
    such matrix in the tensor Frobenius norm); the others are returned unchanged (a
    non-symmetric but positive-definite tangent keeps its skew part). Returns (tangent, repaired mask)."""
    D = np.asarray(D, dtype=float)
    lam, vec = np.linalg.eigh(_mandel(D))
    return _floored(D, lam, vec, floor)


def _floored(D: np.ndarray, lam: np.ndarray, vec: np.ndarray, floor: float) -> tuple[np.ndarray, np.ndarray]:
    scale = np.abs(lam).max(axis=-1)
    threshold = floor * scale
    repaired = lam[:, 0] < threshold
    out = D.copy()
    if repaired.any():
        idx = np.flatnonzero(repaired)
        lam_r = np.maximum(lam[idx], threshold[idx, None])
        lam_r = np.where(scale[idx, None] > 0, lam_r, 0.0)  # an all-zero tangent stays zero (nothing to scale by)
        M = np.einsum("nij,nj,nkj->nik", vec[idx], lam_r, vec[idx])
        out[idx] = M / _S[:, None] / _S[None, :]
    return out, repaired


def _tangent_array(source) -> np.ndarray:
    """A run file path, a Dataset with a `tangent` variable, or an array [..., 21] / [..., 6, 6] -> [..., 6, 6]."""
    if isinstance(source, (str, Path)):
        from ..data import read_run

        source = read_run(source, required=("tangent",))
    if hasattr(source, "data_vars"):
        if "tangent" not in source:
            raise KeyError("the run has no 'tangent' variable")
        source = source["tangent"].values
    arr = np.asarray(source, dtype=float)
    if arr.shape[-1] == 21:
        return tangent_from_upper(arr)
    if arr.shape[-2:] == (6, 6):
        return arr
    raise ValueError(f"expected tangents [..., 21] or [..., 6, 6], got shape {arr.shape}")


def non_spd_per_step(source) -> np.ndarray:
    """Number of Gauss points per step whose tangent is not positive definite.

    `source`: a run file (path), a run Dataset (tangent(step, gp, tcomp)) or an array
    [steps, gp, 21] / [steps, gp, 6, 6]."""
    D = _tangent_array(source)
    if D.ndim != 4:
        raise ValueError(f"expected tangents per step and Gauss point, got shape {D.shape[:-2]}")
    return non_spd_mask(D).sum(axis=1)


def non_spd_share(source, skip_initial: bool = False) -> float:
    """Share (0–1) of the tangents of a run that are not positive definite (all steps and Gauss points).

    skip_initial leaves out step 0 (the consolidated state, where every reference tangent is elastic)."""
    D = _tangent_array(source)
    if skip_initial and D.ndim == 4:
        D = D[1:]
    mask = non_spd_mask(D)
    return float(mask.mean()) if mask.size else 0.0


# -- wrappers -----------------------------------------------------------------------------
class MaterialWrapper(MaterialPointSet):
    """Delegates everything to `inner`; subclasses change evaluate/step_info."""

    def __init__(self, inner: MaterialPointSet, n_points: int | None = None):
        super().__init__(inner.n_points if n_points is None else n_points)
        self.inner = inner
        self.method = getattr(inner, "method", type(inner).__name__)

    def evaluate(self, strain, need_tangent: bool = True):
        return self.inner.evaluate(strain, need_tangent=need_tangent)

    def commit(self, strain=None) -> None:
        self.inner.commit(strain)

    def checkpoint_key(self) -> dict:
        return self.inner.checkpoint_key()

    def get_state(self) -> dict[str, Any]:
        return self.inner.get_state()

    def set_state(self, state: dict[str, Any]) -> None:
        self.inner.set_state(state)

    def step_info(self) -> dict[str, float]:
        return self.inner.step_info()

    def close(self) -> None:
        self.inner.close()

    def __getattr__(self, name):
        # attributes of the wrapped set (e.g. a surrogate's `history`) stay reachable
        if name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)


class TangentRepair(MaterialWrapper):
    """Eigenvalue-floor repair of the tangents of any material set (config ``newton.tangent_repair``).

    step_info adds, for the committed state, ``tangent_non_spd_points`` (raw tangents not
    positive definite) and ``tangent_repaired_points`` (tangents changed: those plus the
    positive-definite ones below the floor)."""

    def __init__(self, inner: MaterialPointSet, method: str = "eig_floor", floor: float = 1e-3):
        super().__init__(inner)
        if method not in REPAIRS or method == "none":
            raise ValueError(f"config key 'newton.tangent_repair': unknown repair {method!r}; known: {REPAIRS[1:]}")
        if not 0 < floor < 1:
            raise ValueError(f"config key 'newton.tangent_floor' must be in (0, 1), got {floor}")
        self.floor = float(floor)
        self._last_strain = None
        self._trial_counts = self._committed_counts = {"tangent_non_spd_points": 0.0, "tangent_repaired_points": 0.0}

    def evaluate(self, strain, need_tangent: bool = True):
        self._last_strain = np.array(strain, dtype=float)
        stress, tangent = self.inner.evaluate(strain, need_tangent=need_tangent)
        if tangent is not None:
            tangent = np.asarray(tangent, dtype=float)
            lam, vec = np.linalg.eigh(_mandel(tangent))  # one decomposition for the count and the repair
            non_spd = lam[:, 0] <= 0.0
            tangent, repaired = _floored(tangent, lam, vec, self.floor)
            self._trial_counts = {"tangent_non_spd_points": float(non_spd.sum()),
                                  "tangent_repaired_points": float(repaired.sum())}
        return stress, tangent

    def commit(self, strain=None) -> None:
        # re-evaluated with the tangent, so the counts are those of the committed state
        self._trial_at(strain, self._last_strain, need_tangent=True)
        self.inner.commit(strain)
        self._committed_counts = dict(self._trial_counts)

    def step_info(self) -> dict[str, float]:
        return {**self.inner.step_info(), **self._committed_counts}


class NoisyTangent(MaterialWrapper):
    """The inner set's tangent with a random relative perturbation of every entry (stress exact).

        D_noisy = D ∘ (1 + amplitude · E),   E symmetric, entries uniform in [−1, 1]

    like a DEM contact tangent that scatters from one RVE relaxation to the next. E is drawn
    from a generator seeded by (seed, the bytes of the trial strain), so evaluate stays a
    pure function of the trial strain, as the interface requires."""

    def __init__(self, inner: MaterialPointSet, amplitude: float, seed: int = 0):
        super().__init__(inner)
        if not 0 <= amplitude < 1:
            raise ValueError(f"noise amplitude must be in [0, 1), got {amplitude}")
        self.amplitude = float(amplitude)
        self.seed = int(seed)

    def evaluate(self, strain, need_tangent: bool = True):
        strain = self._check_strain(strain)
        stress, tangent = self.inner.evaluate(strain, need_tangent=need_tangent)
        if tangent is not None and self.amplitude > 0:
            rng = np.random.default_rng([self.seed, zlib.crc32(np.ascontiguousarray(strain).tobytes())])
            E = rng.uniform(-1.0, 1.0, size=tangent.shape)
            E = np.triu(E) + np.swapaxes(np.triu(E, 1), -1, -2)
            tangent = tangent * (1.0 + self.amplitude * E)
        return stress, tangent


class UniformField(MaterialWrapper):
    """One material point standing for all `n_points` Gauss points of a homogeneous scene.

    Every evaluation checks that the trial strains agree (max-norm deviation from their median
    ≤ rtol × the strain's magnitude, floored at 10⁻⁶); the single point is evaluated at their
    mean and its stress and tangent are broadcast. A non-uniform trial field raises
    :class:`NonUniformFieldError` naming the Gauss points — it is not a material failure, so
    the solver does not cut back but stops: the scene is not homogeneous (rough platens, a
    heterogeneous material) and needs every point."""

    def __init__(self, single: MaterialPointSet, n_points: int, rtol: float = 1e-8):
        if single.n_points != 1:
            raise ValueError(f"UniformField wraps a set of one material point, got {single.n_points}")
        super().__init__(single, n_points)
        self.rtol = float(rtol)

    def evaluate(self, strain, need_tangent: bool = True):
        strain = self._check_strain(strain)
        # the median names the points that stray from the others (a mean would flag every point)
        typical = np.median(strain, axis=0)
        spread = np.abs(strain - typical).max(axis=1)
        limit = self.rtol * max(float(np.abs(typical).max()), 1e-6)
        bad = np.flatnonzero(spread > limit)
        if bad.size:
            worst = bad[np.argsort(spread[bad])[::-1][:10]]
            raise NonUniformFieldError(
                f"uniform-field material set ({self.method}, one point for {self.n_points}): the trial strains "
                f"differ between Gauss points (largest deviation {spread.max():.3e} from the median at Gauss points "
                f"{worst.tolist()}, allowed {limit:.1e}); the scene is not homogeneous, so it needs every "
                "material point: set specimen.uniform_field to false"
            )
        stress, tangent = self.inner.evaluate(strain.mean(axis=0)[None, :], need_tangent=need_tangent)
        stress = np.broadcast_to(stress, (self.n_points, 6)).copy()
        if tangent is not None:
            tangent = np.broadcast_to(tangent, (self.n_points,) + tangent.shape[1:]).copy()
        return stress, tangent

    def commit(self, strain=None) -> None:
        if strain is not None:
            strain = self._check_strain(strain)
            strain = strain.mean(axis=0)[None, :]  # the one point's strain, as evaluate passed it
        self.inner.commit(strain)


class IsotropicPrestrain(MaterialWrapper):
    """The inner set taken along an isotropic strain to the mean stress ``pressure`` (Pa, compression
    positive), and measured from there: what lets networks trained on RVEs consolidated at p0 start
    a specimen confined at another pressure.

    On construction, per point, the isotropic strain e0·(1, 1, 1, 0, 0, 0) at which the inner
    set's mean stress −tr σ/3 is ``pressure`` (within ``tolerance`` × pressure) is found from trial
    evaluations alone (nothing committed while searching): a bracket grown from e = 0 in the sense
    that moves the mean stress towards the target (e < 0 compresses), within |e| ≤ ``max_prestrain``
    (smaller steps where the inner set fails, e.g. past a cone's apex), then regula falsi (Illinois)
    inside it. That state is then evaluated and committed once: the
    path to it is monotonic, so its state (a surrogate's history variables included) is the same in
    one step as in many. Afterwards, for the solver's strain ε,

        σ(ε) = σ_inner(e0·1 + ε) + offset,   offset = −pressure·1 − σ_inner(e0·1),   D(ε) = D_inner(e0·1 + ε)

    so that ε = 0 gives −pressure·1, the state the specimen starts from in equilibrium with its
    confining traction. The offset is a constant per point: what the search leaves of the mean
    stress (below the tolerance) and the deviatoric stress of the inner set at e0 (a fresh state
    that is not quite isotropic, a network's error along the path); its largest norm is
    :attr:`offset_norm` and is logged. A record the inner set keeps per commit (a surrogate's
    ensemble spread, :attr:`stress_spread`) is given from the solver's first commit on, without the
    commits up to the prestrain, one entry per commit of the solver."""

    def __init__(self, inner: MaterialPointSet, pressure: float, logger: logging.Logger | None = None,
                 tolerance: float = 1e-6, max_prestrain: float = 0.05, max_iterations: int = 200):
        super().__init__(inner)
        if not (np.isfinite(pressure) and pressure > 0):
            raise ValueError(f"isotropic prestrain: the target pressure must be a positive number of Pa, got {pressure}")
        self.pressure = float(pressure)
        self.logger = logger or logging.getLogger(__name__)
        e0 = self._prestrain(tolerance * self.pressure, max_prestrain, max_iterations)
        self.prestrain = e0[:, None] * _ONE
        stress, _ = self.inner.evaluate(self.prestrain, need_tangent=False)
        self.inner.commit(self.prestrain)
        self._commits_before_solver = len(getattr(self.inner, "stress_spread", ()))
        self.offset = -self.pressure * _ONE - stress
        mean = -stress[:, :3].sum(axis=1) / 3.0
        self.logger.info(
            "isotropic prestrain to %.6g Pa: e0 %.4g..%.4g (tr eps %.4g..%.4g), inner mean stress %.6g..%.6g Pa, "
            "stress offset up to %.3g Pa (tensor norm)", self.pressure, e0.min(), e0.max(), 3 * e0.min(), 3 * e0.max(),
            mean.min(), mean.max(), self.offset_norm)

    @property
    def offset_norm(self) -> float:
        """Pa: the largest tensor norm of the stress offset over the points (shear counted twice)."""
        return float(np.sqrt((self.offset**2 * np.array([1.0, 1, 1, 2, 2, 2])).sum(axis=1)).max())

    def _mean_stress(self, e: np.ndarray) -> np.ndarray:
        stress, _ = self.inner.evaluate(e[:, None] * _ONE, need_tangent=False)
        return -stress[:, :3].sum(axis=1) / 3.0

    def _prestrain(self, tolerance: float, max_prestrain: float, max_iterations: int) -> np.ndarray:
        """[n] e0 with |mean stress(e0·1) − pressure| <= tolerance at every point (trial evaluations only)."""
        n = self.n_points
        near, f_near = np.zeros(n), self._mean_stress(np.zeros(n)) - self.pressure
        done = np.abs(f_near) <= tolerance
        sense = np.where(f_near < 0, -1.0, 1.0)  # compression (e < 0) raises the mean stress
        far, f_far = near.copy(), f_near.copy()
        step = np.full(n, 1e-4)
        bracketed = done.copy()
        for _ in range(max_iterations):  # grow the bracket from 0
            growing = ~bracketed
            if not growing.any():
                break
            trial = np.where(growing, np.clip(near + sense * step, -max_prestrain, max_prestrain), near)
            try:
                f = self._mean_stress(trial) - self.pressure
            except MaterialPointError:  # past what the inner set answers (e.g. tension): smaller steps
                step = np.where(growing, 0.5 * step, step)
                continue
            crossed = growing & (np.sign(f) != np.sign(f_near))
            far, f_far = np.where(crossed, trial, far), np.where(crossed, f, f_far)
            bracketed |= crossed
            short = growing & ~crossed
            near, f_near = np.where(short, trial, near), np.where(short, f, f_near)
            if (short & (np.abs(trial) >= max_prestrain)).any():
                break
            step = np.where(short, 2.0 * step, step)
        if not bracketed.all():
            first = np.flatnonzero(~bracketed)
            raise ValueError(
                f"isotropic prestrain: no isotropic strain |e| <= {max_prestrain:g} brings the mean stress of "
                f"{self.method} to the target pressure {self.pressure:g} Pa (Gauss points {first[:10].tolist()}; "
                f"point {first[0]}: {f_near[first[0]] + self.pressure:.6g} Pa at e = {near[first[0]]:.4g}): this "
                "material cannot be brought to that confining pressure")
        # regula falsi with the Illinois halving, inside [near, far] per point, from the better end
        better = np.abs(f_far) < np.abs(f_near)
        e, f_e = np.where(better, far, near), np.where(better, f_far, f_near)
        done = np.abs(f_e) <= tolerance
        for _ in range(max_iterations):
            if done.all():
                break
            secant = far - f_far * (far - near) / np.where(f_far != f_near, f_far - f_near, 1.0)
            inside = (secant - near) * (secant - far) < 0
            trial = np.where(done, e, np.where(inside, secant, 0.5 * (near + far)))
            f = self._mean_stress(trial) - self.pressure
            update = ~done
            e, f_e = np.where(update, trial, e), np.where(update, f, f_e)
            done |= np.abs(f_e) <= tolerance
            switch = update & (np.sign(f) != np.sign(f_far))  # the root is between the trial and far
            f_near = np.where(update & ~switch, 0.5 * f_near, f_near)  # Illinois: the stale end loses weight
            near, f_near = np.where(switch, far, near), np.where(switch, f_far, f_near)
            far, f_far = np.where(update, trial, far), np.where(update, f, f_far)
        if not done.all():
            raise ValueError(
                f"isotropic prestrain: the mean stress of {self.method} did not come within {tolerance:.3g} Pa of the "
                f"target pressure {self.pressure:g} Pa in {max_iterations} iterations (Gauss points "
                f"{np.flatnonzero(~done)[:10].tolist()}; a response that jumps across the target?)")
        return e

    def evaluate(self, strain, need_tangent: bool = True):
        strain = self._check_strain(strain)
        stress, tangent = self.inner.evaluate(self.prestrain + strain, need_tangent=need_tangent)
        return stress + self.offset, tangent

    def commit(self, strain=None) -> None:
        self.inner.commit(None if strain is None else self.prestrain + self._check_strain(strain))

    def checkpoint_key(self) -> dict:
        return {"inner": self.inner.checkpoint_key(), "isotropic_prestrain_pressure": self.pressure}

    def get_state(self) -> dict[str, Any]:
        return {"inner": self.inner.get_state(), "pressure": self.pressure, "prestrain": self.prestrain.copy(),
                "offset": self.offset.copy()}

    def set_state(self, state: dict[str, Any]) -> None:
        if state.get("pressure") != self.pressure:
            raise ValueError(f"the checkpoint's material was prestrained to {state.get('pressure')} Pa, this run's "
                             f"to {self.pressure} Pa")
        prestrain, offset = (np.asarray(state[k], dtype=float) for k in ("prestrain", "offset"))
        if prestrain.shape != (self.n_points, 6) or offset.shape != (self.n_points, 6):
            raise ValueError(f"isotropic prestrain state for {prestrain.shape[0]} points, this set has {self.n_points}")
        self.inner.set_state(state["inner"])
        self.prestrain, self.offset = prestrain.copy(), offset.copy()

    @property
    def stress_spread(self) -> np.ndarray:
        """The inner set's per-commit ensemble spread from the solver's first commit on."""
        return self.inner.stress_spread[self._commits_before_solver:]


class Zoned(MaterialPointSet):
    """Material sets side by side: point i is answered by ``sets[zones[i]]`` (each set holds the
    points of its zone, in order). Used for the analytic models of a heterogeneous body, e.g.
    the weak zone of a biaxial specimen; DEM sets express zones through their packing
    assignment instead. ``step_info`` is the point-weighted mean of the sets' values (the
    analytic sets report fractions and means)."""

    def __init__(self, sets: list[MaterialPointSet], zones):
        zones = np.asarray(zones, dtype=int)
        super().__init__(zones.size)
        if zones.min() < 0 or zones.max() >= len(sets):
            raise ValueError(f"zones must index the {len(sets)} material sets, got values {sorted(set(zones))}")
        self.members = [np.flatnonzero(zones == k) for k in range(len(sets))]
        for k, (inner, idx) in enumerate(zip(sets, self.members)):
            if inner.n_points != idx.size:
                raise ValueError(f"material set {k} has {inner.n_points} points, zone {k} {idx.size}")
        self.sets = list(sets)
        self.zones = zones
        self.method = sets[0].method

    def evaluate(self, strain, need_tangent: bool = True):
        strain = self._check_strain(strain)
        stress = np.empty((self.n_points, 6))
        tangent = np.empty((self.n_points, 6, 6)) if need_tangent else None
        for inner, idx in zip(self.sets, self.members):
            if idx.size:
                s, t = inner.evaluate(strain[idx], need_tangent=need_tangent)
                stress[idx] = s
                if need_tangent:
                    tangent[idx] = t
        return stress, tangent

    def commit(self, strain=None) -> None:
        for inner, idx in zip(self.sets, self.members):
            if idx.size:
                inner.commit(None if strain is None else np.asarray(strain, dtype=float)[idx])

    def checkpoint_key(self) -> dict:
        return {"zones": self.zones.tolist(), "sets": [inner.checkpoint_key() for inner in self.sets]}

    def get_state(self) -> dict[str, Any]:
        return {"zones": self.zones.copy(), "sets": [inner.get_state() for inner in self.sets]}

    def set_state(self, state: dict[str, Any]) -> None:
        if not np.array_equal(state["zones"], self.zones):
            raise ValueError("the checkpoint's material zones differ from this run's")
        for inner, inner_state in zip(self.sets, state["sets"]):
            inner.set_state(inner_state)

    def step_info(self) -> dict[str, float]:
        infos = [(inner.step_info(), idx.size) for inner, idx in zip(self.sets, self.members) if idx.size]
        keys = sorted({k for info, _ in infos for k in info})
        return {k: sum(info.get(k, 0.0) * n for info, n in infos) / self.n_points for k in keys}

    def close(self) -> None:
        for inner in self.sets:
            inner.close()


class ZonedSurrogate(Zoned):
    """Networks side by side: the specimen's at zone 0, another material's (the weak zone's) at zone 1.
    What FEM–ML records of its networks comes from the specimen's set (``sets[0]``: its model
    files, ensemble size, features and training pressure); the ensemble spread is gathered per
    point from each zone's set, the out-of-range points are counted over all of them."""

    def __init__(self, sets: list[MaterialPointSet], zones):
        super().__init__(sets, zones)
        sizes = {inner.ensemble_size for inner in sets}
        if len(sizes) != 1:
            raise ValueError(f"the zones' networks must be ensembles of one size (their spreads are compared), "
                             f"got {sorted(sizes)}")

    def __getattr__(self, name):
        # the specimen's networks stand for the run (ensemble_size, tangent, feature_names, sigma_model...)
        if name == "sets":
            raise AttributeError(name)
        return getattr(self.sets[0], name)

    @property
    def stress_spread(self) -> np.ndarray:
        """[committed states, n_points, 6] each point's spread, from its zone's networks."""
        spreads = [inner.stress_spread for inner in self.sets]
        commits = {spread.shape[0] for spread in spreads}
        if len(commits) != 1:
            raise RuntimeError(f"the zones' networks recorded {sorted(commits)} committed states, not one number")
        out = np.zeros((commits.pop(), self.n_points, 6))
        for spread, idx in zip(spreads, self.members):
            out[:, idx] = spread
        return out

    def step_info(self) -> dict[str, float]:
        infos = [inner.step_info() for inner, idx in zip(self.sets, self.members) if idx.size]
        keys = sorted({k for info in infos for k in info})
        return {k: (max if k.endswith("excess") else sum)(info.get(k, 0.0) for info in infos) for k in keys}
