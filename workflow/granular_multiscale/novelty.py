"""Whether a state is off the training data: the distance to the k nearest training states.

A box of per-feature ranges (the material's out-of-range check) misses a combination of
features that no training state has: inside every feature's range, yet far from every training
state. A distance to the training states does not. The networks' material set flags such
states at every commit (``surrogate.material``), and the analysis counts them along the runs
(``analysis.problem_surrogate``)."""

from __future__ import annotations

import numpy as np

#: the neighbour whose distance counts (the k-th nearest)
NEIGHBOURS = 5
#: a state is off the training data when its k-th neighbour is farther than this quantile of the
#: training states' own (leave-one-out) k-th neighbour distances
NOVELTY_QUANTILE = 0.99


class TrainingStates:
    """The training samples' inputs, each scaled by its training range, and the distance to the k-th
    nearest training state that counts as inside the data (:data:`NOVELTY_QUANTILE` of the training
    states' own leave-one-out distances). A box of per-feature ranges misses a combination of
    features that no training state has; a distance to the training states does not."""

    def __init__(self, train_features: np.ndarray, k: int = NEIGHBOURS, radius: float | None = None):
        """`radius`: the one measured before on the same states (a model file keeps it: measuring it
        queries every training state, seconds for 20 000 of them)."""
        from scipy.spatial import cKDTree

        x = np.asarray(train_features, dtype=float)
        self.lo = x.min(axis=0)
        self.span = np.where(np.ptp(x, axis=0) > 0, np.ptp(x, axis=0), 1.0)
        self.k = int(k)
        self.tree = cKDTree((x - self.lo) / self.span)
        if radius is None:
            own, _ = self.tree.query(self.tree.data, k=self.k + 1)  # the first neighbour is the state itself
            radius = float(np.quantile(own[:, -1], NOVELTY_QUANTILE))
        self.radius = float(radius)

    def distance(self, features: np.ndarray) -> np.ndarray:
        """[...] the distance of each state [..., f] to its k-th nearest training state (training range units)."""
        shape = features.shape[:-1]
        d, _ = self.tree.query(((features - self.lo) / self.span).reshape(-1, features.shape[-1]), k=self.k)
        return d[:, -1].reshape(shape)

    def off(self, features: np.ndarray) -> np.ndarray:
        """[...] True where a state is farther from the training states than :attr:`radius`."""
        return self.distance(features) > self.radius


class OffTrainingTracker:
    """Which committed states are off the training data: exactly :meth:`TrainingStates.off`'s answer,
    without a k-d tree query for the points that are surely inside.

    The k training states nearest to a point when it was last queried are still k training
    states, at distances of at most the largest of theirs to its new state: when that bound is
    inside the radius, so is the k-th nearest. Between two commits a point moves little against the
    radius, so most points are settled by k distances; the others are queried as before, and their
    neighbours renewed. (A query of all 128 points of the triaxial specimen against 20 000 training
    states takes about 1.5 ms, a tenth of the FEM–ML run of Path2 when made at every commit.) The
    bound must clear the radius by a margin (1e-9 of it), so that round-off never decides."""

    MARGIN = 1e-9

    def __init__(self, states: TrainingStates):
        self.states = states
        self.neighbours: np.ndarray | None = None  # [n, k] of each point's last query

    def __call__(self, features: np.ndarray) -> np.ndarray:
        """[n, f] features -> [n] True where the k-th nearest training state is farther than the radius."""
        states = self.states
        scaled = (features - states.lo) / states.span
        if self.neighbours is None or self.neighbours.shape[0] != scaled.shape[0]:
            self.neighbours = np.zeros((scaled.shape[0], states.k), dtype=np.intp)
            asked = np.ones(scaled.shape[0], dtype=bool)
        else:
            bound = np.linalg.norm(states.tree.data[self.neighbours] - scaled[:, None, :], axis=-1).max(axis=1)
            asked = bound > states.radius * (1.0 - self.MARGIN)
        off = np.zeros(scaled.shape[0], dtype=bool)
        if asked.any():
            distance, index = states.tree.query(scaled[asked], k=states.k)
            n_asked = int(asked.sum())
            off[asked] = distance.reshape(n_asked, -1)[:, -1] > states.radius
            self.neighbours[asked] = index.reshape(n_asked, -1)
        return off


def sample_states(features: np.ndarray, n_max: int, seed: int) -> np.ndarray:
    """At most `n_max` of the rows of `features` [n, f], drawn without replacement (all when fewer):
    what a model file keeps of its training inputs."""
    features = np.asarray(features, dtype=float)
    if len(features) <= n_max:
        return features.copy()
    return features[np.sort(np.random.default_rng(seed).choice(len(features), n_max, replace=False))]
