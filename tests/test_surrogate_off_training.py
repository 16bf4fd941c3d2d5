"""The off-training check at a commit (novelty.OffTrainingTracker) settles most points by
their last neighbours instead of a k-d tree query: it must give TrainingStates.off's answer exactly,
commit after commit, as points wander into and out of the training data."""

import numpy as np

from granular_multiscale.novelty import OffTrainingTracker, TrainingStates


class CountingTree:
    """The k-d tree of a TrainingStates, counting the points it is asked about."""

    def __init__(self, tree):
        self.tree, self.data, self.asked = tree, tree.data, 0

    def query(self, x, k):
        self.asked += len(x)
        return self.tree.query(x, k=k)


def test_the_neighbour_bound_gives_the_tree_query_answer_at_every_commit():
    rng = np.random.default_rng(0)
    slab = np.array([1.0, 1.0, 0.2, 1.0])  # the training data: a large third feature is off it
    states = TrainingStates(rng.uniform(size=(3000, 4)) * slab)
    reference = TrainingStates(states.tree.data * states.span + states.lo, radius=states.radius)
    states.tree = CountingTree(states.tree)
    check = OffTrainingTracker(states)
    n, steps = 40, 60
    start = rng.uniform(size=(n, 4)) * slab
    drift = rng.normal(scale=0.003, size=(n, 4))
    drift[::2, 2] += 0.006  # half the points leave the slab, the others stay near where they start
    off = []
    for step in range(steps):
        features = start + step * drift + rng.normal(scale=1e-3, size=(n, 4))
        off.append(check(features))
        np.testing.assert_array_equal(off[-1], reference.off(features))
    assert 0 < off[-1].sum() < n and not off[0].any()  # some points left the data, not all
    # a point off the data is asked at every commit, most of those inside are settled without a query
    assert states.tree.asked < 0.75 * n * steps
