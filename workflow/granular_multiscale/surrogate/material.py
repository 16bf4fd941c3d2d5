"""The trained networks as a material-point set: what FEM–ML puts at the Gauss points.

Per Newton iteration every Gauss point is answered by ONE batched forward pass (no loop
over points). With ε_c, Δε_acc,c and ψ_c the converged strain, accumulated increment and
running strain maxima of the last committed step and ε the trial strain (``history`` module),

    Δε_acc = Δε_acc,c + |ε − ε_c|,   φ = φ(Δε_acc),   ψ = max(ψ_c, ‖ε‖),
    x = [ε, the selected ones of φ1, φ2, φ3, ψ1, ψ2],   σ = NNσ(x)

and the history (ε_c, Δε_acc,c, ψ_c) advances only in :meth:`SurrogateMaterial.commit`.

Tangent options (config ``surrogate.tangent``):

* ``nn``: ND(x), its 21 entries reassembled into the symmetric 6×6 Voigt matrix (Pa),
  the paper's choice;
* ``autodiff``: the exact Jacobian of ε ↦ NNσ(ε, φ(ε)), including the chain rule through
  the history variables, which depend on the trial strain (ψ only while the trial norm exceeds
  the converged maximum): forward-mode differentiation of the network in one
  batched pass (``ScaledMLP.forward_with_tangents``; tested against ``torch.func.jacrev``
  and finite differences). The network
  takes tensorial shear, the solver's tangent acts on engineering strain
  (``tensors`` module), so column J is divided by 1 (normal) or 2 (shear).
  This tangent is not symmetric in general.

With ``anchor_initial_state`` (config ``surrogate.anchor_initial_state``, default on) a
constant offset makes both networks reproduce the fresh state (zero strain and history)
exactly: the consolidated stress −p0·1, with which the specimen starts in equilibrium, and
its tangent (see :meth:`SurrogateModel.initial_offset`). Without it, the fit error at the
origin (often a few kPa) puts the specimen out of balance before any load is applied.

Inputs outside the training minimum–maximum are not an error (the networks extrapolate)
but never pass silently: each step's count is logged and returned by :meth:`step_info`
(``out_of_range_points``), which the solver writes to the run file. A feature counts as out
of range when it leaves [min − margin, max + margin], margin = ``out_of_range_tolerance`` ×
its range (+ 1e-9 × its magnitude for round-off), and the excess is measured in that range.
The six strains share one range, the largest span of the six: they share units, and on a
symmetric mesh a shear strain can be zero to round-off at every training point (a span of
1e-17), so that its own span would flag every later roundoff-sized deviation as far out.
Each history variable has its own range.

The box misses a state whose features are each inside their range in a combination no training
state has (a large shear with little dilation, say). A model file that keeps a sample of its
training inputs (``SurrogateModel.training_states``, written by training) also gives the distance
of each committed state to its nearest training states (``novelty.TrainingStates``): a point
farther than the training states' own 99th percentile is off the training data, counted per
step as ``off_training_points`` in the run file, with a warning whenever more points are off
than in any earlier step.

Ensemble spread (``surrogate.ensemble_size`` K): each evaluation keeps the K members' NNσ
(their mean is the stress; no extra pass), and at every commit
:attr:`SurrogateMaterial.stress_spread` records, per committed state and point, the standard
deviation over the members of each stress component at the committed strain (Pa; population
std, divided by K; 0 for K = 1). With ``anchor_initial_state`` each member is anchored by
its own offset (``SurrogateModel.initial_offset(per_member=True)``), whose mean is the
ensemble's: the members' mean is the stress the solver gets (to round-off), and the spread
is that of the anchored networks, 0 at the fresh state where they are exact by construction. :func:`relative_spread` turns it into a scalar per point. The record is part of
:meth:`SurrogateMaterial.get_state`, so it survives a checkpoint and resume; the FEM–ML driver
writes it into the run file (``stress_spread``, ``stress_spread_relative``).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..history import HIST, accumulate, history_jacobian_torch, history_variables, running_peak, strain_norms
from ..materials.base import MaterialPointSet
from ..novelty import NEIGHBOURS, NOVELTY_QUANTILE, OffTrainingTracker, TrainingStates
from ..tensors import ENGINEERING_FACTOR, UPPER, voigt_to_tensor
from .dataset import STRAIN_FEATURES, strain_history
from .models import SurrogateModel, trial_features

TANGENTS = ("nn", "autodiff")

# gather index that turns the 21 upper-triangle entries into the full symmetric 6×6 matrix
_SYMMETRIC_INDEX = np.empty((6, 6), dtype=np.int64)
for _k, (_i, _j) in enumerate(zip(*UPPER)):
    _SYMMETRIC_INDEX[_i, _j] = _SYMMETRIC_INDEX[_j, _i] = _k

# Roundoff-sized deviations (e.g. a shear strain that is 1e-18 instead of 0) are not "out of range".
_ROUNDOFF = 1e-9


def spread_floor(confining_pressure: float) -> float:
    """Pa: the smallest stress norm :func:`relative_spread` divides by, ‖−p0·1‖ = √3·p0, the norm of
    the consolidated stress (a spread relative to a stress near zero would mean nothing)."""
    return float(np.sqrt(3.0) * confining_pressure)


def relative_spread(spread: np.ndarray, stress: np.ndarray, confining_pressure: float) -> np.ndarray:
    """[..., 6] spread and stress (Pa) -> [...]: ‖spread‖ / max(‖stress‖, √3·p0), tensor norms
    (shear components counted twice)."""
    def norm(v):
        return np.linalg.norm(voigt_to_tensor(v), axis=(-2, -1))

    return norm(spread) / np.maximum(norm(stress), spread_floor(confining_pressure))


def method_name(tangent: str, use_history: bool = True) -> str:
    """Name written to the run file's `method` attribute, e.g. 'fem_ml_nn', 'fem_ml_nohist_autodiff'."""
    return f"fem_ml_{'' if use_history else 'nohist_'}{tangent}"


class SurrogateMaterial(MaterialPointSet):
    """NNσ (+ ND) at `n_points` Gauss points; float64 on the CPU."""

    def __init__(
        self,
        n_points: int,
        sigma_model: SurrogateModel,
        tangent_model: SurrogateModel | None = None,
        tangent: str = "nn",
        out_of_range_tolerance: float = 0.0,
        logger: logging.Logger | None = None,
        anchor_initial_state: bool = True,
        consolidation_pressure: float | None = None,
    ):
        super().__init__(n_points)
        if tangent not in TANGENTS:
            raise ValueError(f"config key 'surrogate.tangent' must be one of {TANGENTS}, got {tangent!r}")
        if sigma_model.kind != "sigma":
            raise ValueError(f"the stress model must be an NNσ (kind 'sigma'), got kind {sigma_model.kind!r}")
        if tangent == "nn":
            if tangent_model is None:
                raise ValueError("surrogate.tangent 'nn' needs the ND model (kind 'tangent')")
            if tangent_model.kind != "tangent":
                raise ValueError(f"the tangent model must be an ND (kind 'tangent'), got kind {tangent_model.kind!r}")
            if tangent_model.feature_names != sigma_model.feature_names:
                raise ValueError(
                    f"NNσ and ND take different features: {sigma_model.feature_names} vs {tangent_model.feature_names}"
                )
        if out_of_range_tolerance < 0:
            raise ValueError(f"config key 'surrogate.out_of_range_tolerance' must be >= 0, got {out_of_range_tolerance}")
        self.tangent = tangent
        self.use_history = sigma_model.use_history
        self.method = method_name(tangent, self.use_history)
        self.logger = logger or logging.getLogger(__name__)
        self.dtype = torch.float64
        self.sigma_model = sigma_model
        self.tangent_model = tangent_model if tangent == "nn" else None
        self._sigma_net = sigma_model.network.to(self.dtype)
        self._tangent_net = self.tangent_model.network.to(self.dtype) if self.tangent_model else None
        self._eng = torch.as_tensor(ENGINEERING_FACTOR, dtype=self.dtype)
        self._sym = torch.as_tensor(_SYMMETRIC_INDEX.ravel())
        self._range_bounds(out_of_range_tolerance)
        states = sigma_model.training_states
        self._training_states = (TrainingStates(states, radius=sigma_model.training_radius)
                                 if states is not None and len(states) > NEIGHBOURS else None)
        self._off_training = OffTrainingTracker(self._training_states) if self._training_states is not None else None
        self._off_training_most = 0  # the most points off the training data in one committed state yet
        self.anchor_initial_state = bool(anchor_initial_state)
        self.ensemble_size = sigma_model.ensemble_size
        self.set_consolidation_pressure(consolidation_pressure)

        self._strain_c = np.zeros((self.n_points, 6))
        self._acc_c = np.zeros((self.n_points, 6))
        self._peak_c = np.zeros((self.n_points, 2))  # running maxima (ψ1, ψ2) of the converged steps
        self._trial: np.ndarray | None = None
        self._trial_members: torch.Tensor | None = None
        self._trial_out_of_range: tuple[np.ndarray, np.ndarray] | None = None
        self._trial_distance: np.ndarray | None = None
        self._step_info = {"out_of_range_points": 0.0, "out_of_range_excess": 0.0}
        self._commits = 0
        self._spread: list[np.ndarray] = []  # per committed state: [n_points, 6] std over the members (Pa)

    @classmethod
    def from_files(
        cls,
        n_points: int,
        sigma_path: str | Path,
        tangent_path: str | Path | None = None,
        tangent: str = "nn",
        out_of_range_tolerance: float = 0.0,
        logger: logging.Logger | None = None,
        anchor_initial_state: bool = True,
        consolidation_pressure: float | None = None,
    ) -> "SurrogateMaterial":
        sigma = SurrogateModel.load(sigma_path)
        nd = SurrogateModel.load(tangent_path) if (tangent == "nn" and tangent_path is not None) else None
        return cls(n_points, sigma, nd, tangent, out_of_range_tolerance, logger, anchor_initial_state,
                   consolidation_pressure)

    def set_consolidation_pressure(self, pressure: float | None) -> None:
        """p0 (Pa) of every point, for networks that take it (``SurrogateModel.takes_pressure``): the
        input, and the fresh state's offsets at that pressure. Networks that do not take it ignore it."""
        takes = self.sigma_model.takes_pressure
        if takes and (pressure is None or not np.isfinite(pressure) or pressure <= 0):
            raise ValueError(f"the networks take p0, the consolidation pressure: expected a positive number of Pa, "
                             f"got {pressure!r}")
        self.consolidation_pressure = float(pressure) if takes else None
        self._pressure = torch.tensor(self.consolidation_pressure, dtype=self.dtype) if takes else None
        self._sigma_offset = self._offset(self.sigma_model)
        self._tangent_offset = self._offset(self.tangent_model) if self.tangent_model else None
        self._member_offsets = (torch.as_tensor(self.sigma_model.initial_offset(
                                    per_member=True, pressure=self.consolidation_pressure), dtype=self.dtype)
                                if self.anchor_initial_state else torch.zeros(self.ensemble_size, 6, dtype=self.dtype))

    def _offset(self, model: SurrogateModel) -> torch.Tensor:
        n_out = len(model.target_names)
        if not self.anchor_initial_state:
            return torch.zeros(n_out, dtype=self.dtype)
        return torch.as_tensor(model.initial_offset(pressure=self.consolidation_pressure), dtype=self.dtype)

    # ---------------------------------------------------------------- inputs
    def _range_bounds(self, tolerance: float) -> None:
        net = self._sigma_net
        lo = net.x_min.detach().numpy().astype(np.float64)
        hi = net.x_max.detach().numpy().astype(np.float64)
        span = hi - lo
        n_strain = len(STRAIN_FEATURES)
        span[:n_strain] = span[:n_strain].max()  # the strains' shared range (module docstring)
        scale = np.maximum(np.abs(lo), np.abs(hi))
        scale[:n_strain] = max(span[0], scale[:n_strain].max())
        margin = tolerance * span + _ROUNDOFF * scale
        self._lo, self._hi = lo - margin, hi + margin
        self._x_min = lo
        self._span = np.where(span > 0, span, 1.0)
        self.feature_names = self.sigma_model.feature_names

    def _converged(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The converged state (Δε_acc,c, ε_c, ψ_c) as tensors, in the order the feature functions take."""
        return torch.from_numpy(self._acc_c), torch.from_numpy(self._strain_c), torch.from_numpy(self._peak_c)

    def _features(self, strain: torch.Tensor, acc_c, strain_c, peak_c) -> torch.Tensor:
        """[..., 6] trial strain -> [..., 6 + n_history] network features."""
        return trial_features(strain, acc_c, strain_c, peak_c, self.sigma_model.history, self._pressure)

    def _out_of_range(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per point: any feature outside the training range; excess in units of the training range."""
        below = np.maximum(self._lo - x, 0.0)
        above = np.maximum(x - self._hi, 0.0)
        excess = (below + above) / self._span
        return excess > 0, excess

    # ---------------------------------------------------------------- interface
    def evaluate(self, strain: np.ndarray, need_tangent: bool = True):
        strain = self._check_strain(strain)
        eps = torch.from_numpy(strain)
        converged = self._converged()
        with torch.no_grad():
            x = self._features(eps, *converged)
            if need_tangent and self.tangent == "autodiff":
                sigma, jac, members = self._sigma_net.forward_with_tangents_members(
                    x, self._feature_jacobian(eps, *converged))
                sigma = sigma + self._sigma_offset
                tangent = jac / self._eng  # ∂σ/∂ε (tensorial) -> acts on engineering strain
            else:
                sigma, members = self._sigma_net.forward_members(x)
                sigma = sigma + self._sigma_offset
                tangent = None
                if need_tangent:
                    upper = self._tangent_net(x) + self._tangent_offset
                    tangent = upper[:, self._sym].reshape(-1, 6, 6)
        stress = sigma.numpy().copy()
        tangent_np = tangent.numpy().copy() if tangent is not None else None
        self._check_response(stress, tangent_np, self.method)
        self._trial = strain.copy()
        self._trial_members = members  # the members' NNσ: the spread, if this trial is committed
        self._trial_features = x.numpy()
        self._trial_distance = None  # to the training states: measured when asked, once per evaluation
        self._trial_out_of_range = self._out_of_range(x.numpy())
        return stress, tangent_np

    def _feature_jacobian(self, strain, acc_c, strain_c, peak_c) -> torch.Tensor:
        """[n, n_features, 6]: d(features)/d(trial strain), the chain rule through the history variables."""
        n = strain.shape[0]
        eye = torch.eye(6, dtype=strain.dtype).expand(n, 6, 6)
        history = strain_history(self.sigma_model.history)
        parts = [eye]
        if history:
            parts.append(history_jacobian_torch(strain, acc_c, strain_c, peak_c)[:, [HIST.index(h) for h in history], :])
        if self._pressure is not None:  # p0 does not move with the strain
            parts.append(torch.zeros(n, 1, 6, dtype=strain.dtype))
        return torch.cat(parts, dim=1) if len(parts) > 1 else eye

    def _stress_with_aux(self, strain, acc_c, strain_c, peak_c):
        """Reference path for the autodiff tangent (tests): torch.func.jacrev of this function."""
        sigma = self._sigma_net(self._features(strain, acc_c, strain_c, peak_c)) + self._sigma_offset
        return sigma, sigma

    def commit(self, strain=None) -> None:
        self._trial_at(strain, self._trial)
        if self._trial is None:
            raise RuntimeError(f"{type(self).__name__}.commit() called before evaluate()")
        self._spread.append(self._member_spread(self._trial_members))
        self._acc_c = accumulate(self._acc_c, self._strain_c, self._trial)
        self._peak_c = running_peak(self._peak_c, self._trial)
        self._strain_c = self._trial
        self._commits += 1
        flagged, excess = self._trial_out_of_range
        points = np.flatnonzero(flagged.any(axis=1))
        self._step_info = {
            "out_of_range_points": float(points.size),
            "out_of_range_excess": float(excess.max()) if excess.size else 0.0,
        }
        if self._training_states is not None:
            if self._trial_distance is not None:  # measured already (the adaptive set's indicator)
                self._note_off_training(self._trial_distance > self._training_states.radius)
            else:
                self._note_off_training(self._off_training(self._trial_features))
        if points.size:
            features = [self.feature_names[j] for j in np.flatnonzero(flagged.any(axis=0))]
            self.logger.warning(
                "%s: committed state %d has %d of %d Gauss points with inputs outside the training range "
                "(features %s; largest excess %.2g of the training range; first points %s)",
                self.method, self._commits, points.size, self.n_points, ", ".join(features),
                self._step_info["out_of_range_excess"], points[:5].tolist(),
            )
        self._trial = None

    def _note_off_training(self, off: np.ndarray) -> None:
        """Count the committed points off the training data (step_info ``off_training_points``); warn
        when more are off than in any earlier committed state (not at every step: in a shear band the
        same points stay off for the rest of the run)."""
        self._step_info["off_training_points"] = float(off.sum())
        if off.sum() > self._off_training_most:
            self._off_training_most = int(off.sum())
            self.logger.warning(
                "%s: committed state %d has %d of %d Gauss points off the training data (farther from their "
                "%d nearest training states than %.0f %% of the training states are; first points %s)",
                self.method, self._commits, off.sum(), self.n_points, self._training_states.k,
                100 * NOVELTY_QUANTILE, np.flatnonzero(off)[:5].tolist())

    def _member_spread(self, members: torch.Tensor) -> np.ndarray:
        """[K, n, 6] members' NNσ -> [n, 6] std over the anchored members (zeros for one network)."""
        if self.ensemble_size == 1:
            return np.zeros((self.n_points, 6))
        return (members + self._member_offsets[:, None, :]).std(dim=0, unbiased=False).numpy().copy()

    def trial_uncertainty(self) -> tuple[np.ndarray, np.ndarray]:
        """Of the last evaluation: [n, 6] ensemble spread of NNσ (Pa, as :attr:`stress_spread` records
        it at a commit) and [n] the largest out-of-range excess over the features (in units of the
        training range, 0 inside it). What the adaptive set decides promotions on."""
        if self._trial is None:
            raise RuntimeError(f"{type(self).__name__}.trial_uncertainty() needs an evaluation first")
        _, excess = self._trial_out_of_range
        return self._member_spread(self._trial_members), excess.max(axis=1, initial=0.0)

    @property
    def knows_training_states(self) -> bool:
        """Whether the model file kept its training inputs (what :meth:`trial_novelty` needs)."""
        return self._training_states is not None

    def trial_distance_ratio(self) -> np.ndarray:
        """[n] of the last evaluation: each point's distance to its k-th nearest training state over
        the radius that 99 % of the training states are within (1 at the edge of the data)."""
        if self._trial is None:
            raise RuntimeError(f"{type(self).__name__}.trial_distance_ratio() needs an evaluation first")
        if self._training_states is None:
            raise ValueError("the NNσ model file keeps no training states (trained before they were kept): "
                             "retrain it to measure the distance to the training data")
        return self._distance_to_training() / self._training_states.radius

    def trial_novelty(self) -> np.ndarray:
        """[n] of the last evaluation: how far each point is beyond the training data,
        :meth:`trial_distance_ratio` minus 1 (0 inside the data; 1 at twice the radius)."""
        return np.maximum(self.trial_distance_ratio() - 1.0, 0.0)

    def _distance_to_training(self) -> np.ndarray:
        """[n] the last evaluation's distance to the k-th nearest training state (the indicator and the
        commit of one evaluation share it)."""
        if self._trial_distance is None:
            self._trial_distance = self._training_states.distance(self._trial_features)
        return self._trial_distance

    def trial_scaled_features(self) -> np.ndarray:
        """[n, features] the network inputs of the last evaluation, in units of their training range
        from its minimum (the strains share one range, as for the out-of-range excess): 0..1 inside it."""
        if self._trial is None:
            raise RuntimeError(f"{type(self).__name__}.trial_scaled_features() needs an evaluation first")
        return (self._trial_features - self._x_min) / self._span

    def trial_scaled_feature_jacobian(self) -> np.ndarray:
        """[n, features, 6] d(trial_scaled_features)/d(strain) at the last evaluation, with the strain
        as the tangent takes it (engineering shears) and the chain rule through the history variables."""
        if self._trial is None:
            raise RuntimeError(f"{type(self).__name__}.trial_scaled_feature_jacobian() needs an evaluation first")
        with torch.no_grad():
            jacobian = self._feature_jacobian(torch.from_numpy(self._trial), *self._converged()) / self._eng
        return jacobian.numpy() / self._span[:, None]

    @property
    def stress_spread(self) -> np.ndarray:
        """[committed states, n_points, 6] the ensemble spread of NNσ at each commit so far (Pa)."""
        return np.asarray(self._spread, dtype=float).reshape(len(self._spread), self.n_points, 6)

    def step_info(self) -> dict[str, float]:
        return dict(self._step_info)

    def get_state(self) -> dict[str, Any]:
        return {"strain": self._strain_c.copy(), "accumulated": self._acc_c.copy(), "peak": self._peak_c.copy(),
                "commits": self._commits, "stress_spread": self.stress_spread}

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a converged state of :meth:`get_state`. A state without ``peak`` (the running maxima
        ψ1, ψ2; a checkpoint written before they existed, or a hand-made state) is taken to be at its
        peak: ψ = the norms of its strain."""
        strain = np.asarray(state["strain"], dtype=float)
        acc = np.asarray(state["accumulated"], dtype=float)
        if strain.shape != (self.n_points, 6) or acc.shape != (self.n_points, 6):
            raise ValueError(f"state for {strain.shape[0]} points, this set has {self.n_points}")
        norms = strain_norms(strain)
        peak = np.asarray(state["peak"], dtype=float) if "peak" in state else norms
        if peak.shape != (self.n_points, 2):
            raise ValueError(f"state 'peak' (running maxima ψ1, ψ2) has shape {peak.shape}, expected ({self.n_points}, 2)")
        below = np.flatnonzero((peak < norms * (1 - 1e-12)).any(axis=1))
        if below.size:
            raise ValueError(f"state 'peak' is below the norm of the converged strain at points {below[:5].tolist()}: "
                             "not a running maximum")
        commits = int(state.get("commits", 0))
        spread = np.asarray(state.get("stress_spread", np.zeros((0, self.n_points, 6))), dtype=float)
        if spread.shape != (commits, self.n_points, 6):
            raise ValueError(f"state of {commits} committed states at {self.n_points} points holds an ensemble-spread "
                             f"record of shape {spread.shape} (a checkpoint written before the spread was recorded?)")
        self._strain_c, self._acc_c, self._peak_c = strain.copy(), acc.copy(), peak.copy()
        self._commits = commits
        self._spread = list(spread)
        self._trial = None

    @property
    def history(self) -> np.ndarray:
        """[n, 5] the variables of ``history.HIST`` (φ1–φ3, ψ1, ψ2) of the converged state."""
        return history_variables(self._acc_c, self._peak_c)
