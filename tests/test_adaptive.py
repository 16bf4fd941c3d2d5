"""Adaptive FEM–DEM–ML (issue 14) at the tiny scale with real YADE RVEs and real (quickly trained)
networks: the DEM subset's replay, and the adaptive set at its two ends and in between.

* a replayed RVE is bit for bit the RVE that followed the same strains from step 0;
* threshold ∞ is FEM–ML and 100 % anchors (or threshold 0) FEM–DEM, bit for bit;
* a run killed after a few steps and started again ends with the numbers of an uninterrupted one.

The networks are an ensemble of 2 NNσ trained in seconds on a synthetic material-point run of the
elastoplastic model (as tests/test_surrogate_uncertainty.py), so they disagree with the
100-sphere RVEs — which makes the mixed specimen a hard case for Newton, not an easy one."""

from __future__ import annotations

import numpy as np
import pytest
from dem_fixtures import SETTINGS, packing

from granular_multiscale.dem.material import DemMaterialPointSet
from granular_multiscale.dem.subset import DemSubsetMaterialPointSet

pytestmark = pytest.mark.slow


def strain_history(n_points: int, n_commits: int, seed: int = 3) -> np.ndarray:
    """[commits, n, 6]: commit 0 at zero strain (the consolidated state), then triaxial-like
    increments of 1e-3 axial with a per-point lateral ratio and shear, one commit repeating the last."""
    rng = np.random.default_rng(seed)
    ratio = rng.uniform(0.3, 0.45, n_points)
    shear = rng.uniform(-0.05, 0.05, (n_points, 3))
    axial = 1e-3 * np.array([0, 1, 2, 3, 3, 2, 4][:n_commits])
    eps = np.zeros((n_commits, n_points, 6))
    eps[..., 0] = eps[..., 1] = ratio * axial[:, None]
    eps[..., 2] = -axial[:, None]
    eps[..., 3:] = shear * axial[:, None, None]
    return eps


def drive(dem, strains, activate: dict | None = None, detour: bool = True) -> None:
    """Commit `strains` one after another; before commit k activate the points activate[k]; with
    `detour`, a discarded trial elsewhere first (what Newton does)."""
    for k, eps in enumerate(strains):
        if activate and k in activate:
            dem.activate(activate[k])
        if detour:
            dem.evaluate(0.5 * eps + 1e-4)
        dem.evaluate(eps)
        dem.commit(eps)


def test_replayed_rve_is_bit_for_bit_the_rve_that_followed_the_strains(tmp_path_factory):
    path, _ = packing(tmp_path_factory)
    n, strains = 4, strain_history(4, 7)
    kwargs = dict(n_workers=2, snapshot_interval=2)  # re-loads after commits 2, 4, 6: the replay must too
    with DemMaterialPointSet(n, [path], SETTINGS, **kwargs) as fem_dem:
        drive(fem_dem, strains, detour=False)
        reference, initial = fem_dem.conv_stress.copy(), fem_dem.initial_stress.copy()
        particle_steps = fem_dem.time_split()["particle_steps"]
    assert np.abs(reference - initial).max() > 1e3  # Pa: the strains did load the RVEs

    with DemSubsetMaterialPointSet(n, [path], SETTINGS, **kwargs) as late:
        drive(late, strains)  # nothing active: no DEM at all
        assert late.time_split()["particle_steps"] == 0 and np.array_equal(late.conv_stress, initial)
        assert late.activate(range(n)) == n  # every point replays 7 commits at once
        assert np.array_equal(late.conv_stress, reference)
        # one DEM increment per commit and point: what FEM–DEM spent without detours
        assert late._step["replay_particle_steps"] == particle_steps > 0

    with DemSubsetMaterialPointSet(n, [path], SETTINGS, **kwargs) as mixed:
        mixed.activate([1])  # an anchor: active from the start
        drive(mixed, strains, activate={3: [0, 2]})  # promoted before commit 3 (after 3 commits)
        assert np.array_equal(mixed.active, [True, True, True, False])
        assert np.array_equal(mixed.conv_stress[:3], reference[:3])
        assert np.array_equal(mixed.conv_stress[3], initial[3])  # never driven: the packing's state
        state = mixed.get_state()
        assert state["strain_record"].shape == (8, n, 6)
        # resume: a fresh set replays the active points (bit for bit), and both continue alike
        with DemSubsetMaterialPointSet(n, [path], SETTINGS, **kwargs) as resumed:
            resumed.set_state(state)
            assert np.array_equal(resumed.conv_stress, mixed.conv_stress)
            last = strains[-1] + np.array([0.0003, 0.0003, -0.001, 0.0, 0.0, 0.0])
            for dem in (mixed, resumed):
                dem.evaluate(last)
                dem.commit(last)
            assert np.array_equal(resumed.conv_stress, mixed.conv_stress)
            assert np.array_equal(resumed.strain_record[-1], last)
