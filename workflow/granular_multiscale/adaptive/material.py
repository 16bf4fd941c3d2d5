"""Adaptive FEM–DEM–ML: the surrogate at every Gauss point, a YADE RVE where it is unsure.

    points = AdaptiveMaterialPointSet(surrogate, dem, threshold=0.05, indicator="spread")
    problem.run(points, load_path)          # the same solver: no `if adaptive` in fem/

One more material-point set. Each point is in one of two modes:

* **surrogate**: the ensemble mean of NNσ and its tangent (:class:`SurrogateMaterial`);
* **DEM**: its own YADE RVE (:class:`DemSubsetMaterialPointSet`: RVEs at every point, only the
  DEM-mode ones driven, so the DEM cost is that of the DEM points alone).

The surrogate answers at every point and every evaluation (one batched pass, negligible next to
an RVE): its history variables follow the converged strains everywhere, and its uncertainty is
known everywhere. A point stays DEM once it is DEM.

Indicator (``adaptive.indicator``), per point, from the surrogate's answer at the trial strain:

* ``spread``: the relative ensemble spread ‖std over the members of NNσ‖ / max(‖σ‖, √3·p0)
  (:func:`surrogate.material.relative_spread`, what FEM–ML writes as ``stress_spread_relative``);
* ``out_of_range``: the largest excess of a feature outside the training range, in units of that
  range (0 inside; :meth:`SurrogateMaterial.trial_uncertainty`);
* ``max``: max(spread, w · excess), w = ``adaptive.out_of_range_weight``: both normalised by their
  thresholds (w = spread threshold / excess threshold), so that one threshold moves both;
* ``off_training``: how far the point's inputs are beyond the training data, d / r − 1 with d the
  distance to its 5th-nearest training state and r the distance within which 99 % of the training
  states have theirs (0 inside the data; :meth:`SurrogateMaterial.trial_novelty`, ``novelty``).
  Unlike the box of ``out_of_range`` it sees a combination of inputs no training state has.
* ``distance``: d / r itself (:meth:`SurrogateMaterial.trial_distance_ratio`): it also ranks the
  points inside the data, where ``off_training`` is 0 for all of them. Where the networks' error
  grows with the distance to what they learnt (the footing: rank correlation 0.85 after the peak),
  a threshold below 1 promotes the points in the sparsest part of the data first.
* ``shear_strain``: the point's equivalent shear strain ε_s = √(2/3)·‖dev ε‖ at the trial strain,
  no statement of the networks at all: DEM where the field localises, the points of a shear band
  first (its threshold is a strain).

A surrogate point is promoted when its indicator is **≥ threshold**: threshold 0 is DEM at every
point from the first evaluation on (FEM–DEM), threshold ∞ never (FEM–ML).

When promotions happen, and why no step is solved twice
-------------------------------------------------------
The method asks for promotion after a converged step and the step solved again with the mixed
set. The set cannot make the solver repeat a step, and a promotion that only takes effect at the
next step would leave the flagged step answered by the surrogate. Instead the indicator is
checked at **every evaluation**, the predictor's (the first of each step) included, and a point
whose indicator reaches the threshold is promoted inside that evaluation: its RVE replays the
point's converged strain history from the consolidated packing up to the last converged step
(:meth:`DemSubsetMaterialPointSet.activate`: one DEM increment and commit per past commit,
batched over all points promoted in that evaluation), and the same evaluation already answers
from it. Newton then goes on with the mixed set from where it is; its trials always start from
the last converged state, so the step it converges is the step "solved again with the mixed set
from the last converged state", without a second solve. What this buys:

* the converged state of every step satisfies: every surrogate point's indicator at its converged
  strain is below the threshold (the last evaluation of a converged step is at the converged
  strain, and it promoted whatever reached the threshold there);
* no lag: a point is never answered by the surrogate in a step at whose converged strain it is
  flagged;
* a promotion in a Newton attempt that is then cut back stays (the RVE is at the last converged
  state, where the cutback's sub-steps start).

The cost: an intermediate Newton iterate may reach the threshold where the converged strain
would not, so a point may be promoted early (conservative: more DEM, never less accuracy), and
``evaluate`` is repeatable within a step only between promotions (a promotion changes the answer
at the promoted points, monotonically, at most once per point).

Correction of the surrogate points (``adaptive.correction``)
-----------------------------------------------------------
The surrogate also answers at the DEM points, so every evaluation with DEM points measures the
networks' error there: the residual r = σ_RVE − σ_NN at the same strain and history. Where the
networks are off by a similar amount over the whole specimen (an unloading branch learnt a little
too stiff: docs/adaptive.md), that residual also holds at the surrogate points in similar states.
With ``correction: kernel`` every surrogate point j gets σ_NN,j + Σ_i w_ji r_i over the DEM points
i, the Nadaraya–Watson weights of a Gaussian kernel of width ``correction_length`` in the networks'
inputs (strain and history, in units of their training range, :func:`residual_correction`):
the residual of the DEM points in the most similar states, a smooth function of the trial. Its
dependence on the point's own strain (the weights move with its inputs) is in the point's tangent
(:func:`residual_correction_jacobian` through the inputs' Jacobian; ``correction_tangent: false``
leaves it out, to measure what it buys); its dependence on the DEM points' strains is left out (it
couples points), and Newton converges on the residual all the same. No DEM point, or no surrogate
point, leaves nothing to correct: threshold ∞ is still FEM–ML and threshold 0 FEM–DEM, bit for
bit. ``correction: local_kernel`` divides the
kernel values by max(1, their sum) instead of their sum: the correction fades to zero at a point
whose state is a few widths from every DEM point's, instead of carrying the nearest residual. Anchors (``anchor_fraction``) make the
DEM points that measure the residual from step 0 on, without replay.

Recorded (:meth:`step_info` per commit, :attr:`commit_log`, :attr:`indicator_log`,
:attr:`promoted_at`): the number of DEM points, the promotions, the DEM particle-steps of the
trials (``particle_steps``) and of the replays (``replay_particle_steps``), and the DEM time
split of FEM–DEM. ``promoted_at[gp]``: the commits done when the point was promoted (it answers
from DEM from commit promoted_at + 1 on; 0 for anchors, −1 never); :meth:`point_mode` turns it
into the mode per commit. Anchors (``adaptive.anchor_fraction``): a seeded random share of the
points in DEM mode from the start (:func:`anchor_points`).

Controls (``schedule``): the same set with the networks replaced by another material-point set
(the elastoplastic model fitted to Path1, or the elastic one) and the promotions of a network run
copied: point p turns DEM at the commit ``schedule[p]`` of that run (−1 never), whatever the
control's own state. The control then spends the same DEM work on the same points at the same
time; what differs is only what answers at the other points. A method that does not beat its
control at the same DEM share measures how uniform the scene is, not the networks.

Checkpoints: :meth:`get_state` holds the surrogate's state, the DEM subset's (its strain
record and active points: it resumes by replaying them, bit for bit) and the records above.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from ..dem.subset import DemSubsetMaterialPointSet
from ..history import equivalent_shear_strain
from ..materials.base import MaterialPointSet
from ..surrogate.material import SurrogateMaterial, relative_spread

INDICATORS = ("spread", "out_of_range", "max", "off_training", "distance", "shear_strain")
#: the indicator of a control run: the promotions of another run, copied
SCHEDULE = "schedule"
CORRECTIONS = ("none", "kernel", "local_kernel")
STATE_FORMAT = "adaptive-state-v1"


def residual_correction(x_surrogate: np.ndarray, x_dem: np.ndarray, residual: np.ndarray,
                        length: float, local: bool = False) -> np.ndarray:
    """[n_s, 6] the DEM points' residual carried to the surrogate points: Nadaraya–Watson weights of a
    Gaussian kernel of width `length` between the inputs x_surrogate [n_s, f] and x_dem [m, f] (in
    units of the training range), applied to residual [m, 6]. The weights of a point sum to 1: as
    `length` → 0 the residual of its nearest DEM point, `length` = inf the mean residual.

    With `local`, the kernel values k = exp(−d²/2ℓ²) are divided by max(1, Σk) instead of Σk: a
    surrogate point at a DEM point's state gets its full residual, one whose nearest DEM state is
    a few widths away almost nothing (the correction fades to zero where no DEM point is in a
    similar state, instead of carrying the nearest residual however far it is)."""
    if np.isinf(length):
        return np.broadcast_to(residual.mean(axis=0), (x_surrogate.shape[0], residual.shape[1])).copy()
    weights, _ = _correction_weights(x_surrogate, x_dem, length, local)
    return weights @ residual


def residual_correction_jacobian(x_surrogate: np.ndarray, x_dem: np.ndarray, residual: np.ndarray,
                                 length: float, local: bool = False) -> np.ndarray:
    """[n_s, 6, f] d(residual_correction)/d(x_surrogate), each surrogate point's own inputs moving,
    the DEM points' held. With k_i = exp(−|x − x_i|²/2ℓ²) and w_i = k_i / N:
    dw_i/dx = w_i [(x_i − x) − c Σ_l w_l (x_l − x)] / ℓ², with c = 1 where N = Σk (the weights sum to
    1 and move only relative to each other) and c = 0 where `local` divides by 1 (Σk < 1). The mean
    residual (`length` inf) does not move."""
    n_s, f = x_surrogate.shape
    if np.isinf(length):
        return np.zeros((n_s, residual.shape[1], f))
    weights, normalised = _correction_weights(x_surrogate, x_dem, length, local)
    offsets = x_dem[None, :, :] - x_surrogate[:, None, :]  # [n_s, m, f]: x_i − x
    mean_offset = np.einsum("sm,smf->sf", weights, offsets)
    d_weights = weights[:, :, None] * (offsets - normalised[:, None, None] * mean_offset[:, None, :]) / length**2
    return np.einsum("mc,smf->scf", residual, d_weights)


def _correction_weights(x_surrogate: np.ndarray, x_dem: np.ndarray, length: float,
                        local: bool) -> tuple[np.ndarray, np.ndarray]:
    """([n_s, m] the correction's weights, [n_s] 1.0 where they are normalised to sum 1, else 0.0)."""
    d2 = ((x_surrogate[:, None, :] - x_dem[None, :, :]) ** 2).sum(axis=-1)
    logits = -d2 / (2.0 * length**2)
    if local:
        kernel = np.exp(logits)
        total = kernel.sum(axis=1, keepdims=True)
        return kernel / np.maximum(total, 1.0), (total[:, 0] > 1.0).astype(float)
    weights = np.exp(logits - logits.max(axis=1, keepdims=True))  # the nearest gets exp(0): no underflow to 0/0
    return weights / weights.sum(axis=1, keepdims=True), np.ones(x_surrogate.shape[0])


def anchor_points(n_points: int, fraction: float, seed: int) -> np.ndarray:
    """The sorted points that run DEM from step 0: round(fraction · n) of them, a seeded random pick."""
    if not 0.0 <= fraction <= 1.0:
        raise ValueError(f"config key 'adaptive.anchor_fraction' must be in [0, 1], got {fraction}")
    count = int(round(fraction * n_points))
    return np.sort(np.random.default_rng(seed).choice(n_points, size=count, replace=False))


class AdaptiveMaterialPointSet(MaterialPointSet):
    method = "adaptive"

    def __init__(self, surrogate: SurrogateMaterial, dem: DemSubsetMaterialPointSet, threshold: float,
                 confining_pressure: float, indicator: str = "spread", out_of_range_weight: float = 1.0,
                 anchors=(), logger: logging.Logger | None = None, correction: str = "none",
                 correction_length: float = 0.05, schedule=None, correction_tangent: bool = True):
        super().__init__(surrogate.n_points)
        if dem.n_points != surrogate.n_points:
            raise ValueError(f"the surrogate has {surrogate.n_points} points, the DEM set {dem.n_points}")
        if not float(threshold) >= 0.0:  # also refuses NaN
            raise ValueError(f"config key 'adaptive.thresholds': a threshold must be >= 0 (or .inf), got {threshold}")
        if indicator not in INDICATORS and schedule is None:
            raise ValueError(f"config key 'adaptive.indicator' must be one of {INDICATORS}, got {indicator!r}")
        if not out_of_range_weight >= 0.0:
            raise ValueError(f"config key 'adaptive.out_of_range_weight' must be >= 0, got {out_of_range_weight}")
        if indicator in ("off_training", "distance") and schedule is None and not surrogate.knows_training_states:
            raise ValueError(f"config key 'adaptive.indicator' {indicator!r} needs networks whose model file keeps "
                             "their training states: retrain them (rules train_*)")
        if correction not in CORRECTIONS:
            raise ValueError(f"config key 'adaptive.correction' must be one of {CORRECTIONS}, got {correction!r}")
        if not float(correction_length) > 0.0:
            raise ValueError(f"config key 'adaptive.correction_length' must be > 0 (or .inf), got {correction_length}")
        if schedule is not None:
            schedule = np.asarray(schedule, dtype=int)
            if schedule.shape != (surrogate.n_points,):
                raise ValueError(f"a promotion schedule needs one commit per point ({surrogate.n_points}), "
                                 f"got shape {schedule.shape}")
            if correction != "none":
                raise ValueError("config key 'adaptive.correction': a control run (promotions copied from another "
                                 "run) measures the residual in the networks' inputs, which its material has not; "
                                 "use correction: none")
            indicator = SCHEDULE
        self.schedule = schedule
        self.correction, self.correction_length = correction, float(correction_length)
        self.correction_tangent = bool(correction_tangent)
        self.surrogate, self.dem = surrogate, dem
        self.threshold = float(threshold)
        self.indicator = indicator
        self.out_of_range_weight = float(out_of_range_weight)
        self.confining_pressure = float(confining_pressure)
        self.log = logger or logging.getLogger("granular_multiscale.adaptive")
        self.anchors = np.asarray(anchors, dtype=int)
        self.promoted_at = np.full(self.n_points, -1)
        self.commits = 0
        self.commit_log: list[dict[str, float]] = []  # per commit: step_info
        self.indicator_log: list[np.ndarray] = []  # per commit: [n] indicator at the converged strain
        self._last_strain: np.ndarray | None = None
        self._indicator_now: np.ndarray | None = None
        self._correction_now = 0.0  # mean ‖correction‖ at the surrogate points of the last evaluation (Pa)
        self._promotions = 0
        if self.anchors.size:
            self.dem.activate(self.anchors)
            self.promoted_at[self.anchors] = 0

    @property
    def dem_mode(self) -> np.ndarray:
        """[n] True where the point answers from its RVE."""
        return self.promoted_at >= 0

    def point_mode(self) -> np.ndarray:
        """[commits, n] 1 where the point answered from DEM at that commit, 0 from the surrogate."""
        commit = np.arange(1, self.commits + 1)[:, None]
        return ((self.promoted_at[None, :] >= 0) & (self.promoted_at[None, :] < commit)).astype(np.int8)

    def indicator_values(self, stress: np.ndarray, strain: np.ndarray) -> np.ndarray:
        """[n] the indicator of the surrogate's last evaluation, at `strain`, whose stress was `stress`."""
        if self.indicator == "shear_strain":
            return equivalent_shear_strain(strain)
        if self.indicator == "off_training":
            return self.surrogate.trial_novelty()
        if self.indicator == "distance":
            return self.surrogate.trial_distance_ratio()
        spread, excess = self.surrogate.trial_uncertainty()
        if self.indicator == "out_of_range":
            return excess
        relative = relative_spread(spread, stress, self.confining_pressure)
        if self.indicator == "spread":
            return relative
        return np.maximum(relative, self.out_of_range_weight * excess)

    # ------------------------------------------------------------------ interface
    def evaluate(self, strain: np.ndarray, need_tangent: bool = True):
        strain = self._check_strain(strain)
        stress, tangent = self.surrogate.evaluate(strain, need_tangent=need_tangent)
        if self.schedule is None:
            value = self.indicator_values(stress, strain)
            new = np.flatnonzero(~self.dem_mode & (value >= self.threshold))
        else:  # a control: 1 where the copied run had the point in DEM by this commit
            value = ((self.schedule >= 0) & (self.schedule <= self.commits)).astype(float)
            new = np.flatnonzero(~self.dem_mode & (value > 0))
        if new.size:
            self._promote(new, value)
        mode = self.dem_mode
        self._correction_now = 0.0
        if mode.any():
            dem_stress, dem_tangent = self.dem.evaluate(strain, need_tangent=need_tangent)
            if self.correction != "none" and not mode.all():
                x = self.surrogate.trial_scaled_features()
                residual, local = dem_stress[mode] - stress[mode], self.correction == "local_kernel"
                shift = residual_correction(x[~mode], x[mode], residual, self.correction_length, local=local)
                stress[~mode] += shift
                if tangent is not None and self.correction_tangent:  # d shift / dε through the point's own inputs
                    d_shift = residual_correction_jacobian(x[~mode], x[mode], residual, self.correction_length, local)
                    tangent[~mode] += d_shift @ self.surrogate.trial_scaled_feature_jacobian()[~mode]
                self._correction_now = float(np.linalg.norm(shift, axis=1).mean())
            stress[mode] = dem_stress[mode]
            if tangent is not None:
                tangent[mode] = dem_tangent[mode]
        self._last_strain, self._indicator_now = strain.copy(), value
        return stress, tangent

    def _promote(self, points: np.ndarray, value: np.ndarray) -> None:
        self.dem.activate(points)
        self.promoted_at[points] = self.commits
        self._promotions += points.size
        self.log.info("adaptive: %d points promoted to DEM during step commit %d (indicator %s %.3g..%.3g >= "
                      "threshold %g; first points %s), %d DEM points now", points.size, self.commits + 1,
                      self.indicator, value[points].min(), value[points].max(), self.threshold,
                      points[:8].tolist(), int(self.dem_mode.sum()))

    def commit(self, strain=None) -> None:
        self._trial_at(strain, self._last_strain)
        if self._last_strain is None:
            raise RuntimeError(f"{type(self).__name__}.commit() called before evaluate()")
        strain = self._last_strain
        self.surrogate.commit(strain)
        self.dem.commit(strain)
        self.commits += 1
        info = dict(self.dem.step_info())
        info.update({"dem_points": float(self.dem_mode.sum()), "promotions": float(self._promotions),
                     "correction": self._correction_now, **self.surrogate.step_info()})
        self.commit_log.append(info)
        self.indicator_log.append(self._indicator_now.copy())
        self._promotions = 0
        self._last_strain = None

    def step_info(self) -> dict[str, float]:
        """That of the last commit (the DEM time split of FEM–DEM, trial and replay particle-steps,
        dem_points, promotions, the surrogate's out-of-range counts)."""
        return dict(self.commit_log[-1]) if self.commit_log else {}

    def checkpoint_key(self) -> dict:
        return {"dem": self.dem.checkpoint_key(), "threshold": self.threshold, "indicator": self.indicator,
                "out_of_range_weight": self.out_of_range_weight, "anchors": self.anchors.tolist(),
                "correction": self.correction, "correction_length": self.correction_length,
                "correction_tangent": self.correction_tangent,
                "schedule": None if self.schedule is None else self.schedule.tolist()}

    def get_state(self) -> dict[str, Any]:
        return {
            "format": STATE_FORMAT,
            "commits": self.commits,
            "promoted_at": self.promoted_at.copy(),
            "commit_log": [dict(d) for d in self.commit_log],
            "indicator_log": np.asarray(self.indicator_log).reshape(self.commits, self.n_points),
            "surrogate": self.surrogate.get_state(),
            "dem": self.dem.get_state(),
        }

    def set_state(self, state: dict[str, Any]) -> None:
        if not isinstance(state, dict) or state.get("format") != STATE_FORMAT:
            raise ValueError(f"not an adaptive material state (format "
                             f"{state.get('format') if isinstance(state, dict) else type(state)})")
        promoted_at = np.asarray(state["promoted_at"], dtype=int)
        if promoted_at.shape != (self.n_points,):
            raise ValueError(f"checkpoint has {promoted_at.size} points, this run {self.n_points}")
        if not np.array_equal(promoted_at >= 0, np.asarray(state["dem"]["active"])):
            raise ValueError("adaptive checkpoint: the DEM points and the DEM set's active RVEs disagree")
        self.surrogate.set_state(state["surrogate"])
        self.dem.set_state(state["dem"])
        self.commits = int(state["commits"])
        self.promoted_at = promoted_at.copy()
        self.commit_log = [dict(d) for d in state["commit_log"]]
        self.indicator_log = list(np.asarray(state["indicator_log"], dtype=float))
        self._last_strain, self._indicator_now, self._promotions = None, None, 0

    def close(self) -> None:
        for part in (self.surrogate, self.dem):
            part.close()
