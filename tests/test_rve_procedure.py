"""The RVE procedure of FEM–DEM (a strain increment as a constant velocity gradient
for N steps, then one step at rest) against a triaxial test driven directly in YADE.

Small scale: two 100-sphere packings, 30 steps to 3 % axial strain (the peak of these RVEs),
Newton tolerance 1e-3, about a minute. The 400-sphere study with 5 packings to 4.5 % is
``bench/bench_rve_procedure.py``; docs/rve_procedure.md has its conclusions, docs/history.md its numbers.
"""

from __future__ import annotations

import numpy as np
import pytest
from dem_fixtures import packing

from granular_multiscale.studies.uniform_fem_dem import run_fem_dem_uniform
from granular_multiscale.studies.direct_triaxial import (
    DirectSpec,
    at_strains,
    fem_dem_config,
    increments_of,
    peak,
    run_direct,
)

pytestmark = pytest.mark.needs_yade  # one RVE, direct and through the FEM solver
P0 = 1.0e5
SEEDS = (0, 1)
END = 0.03
POINTS = np.round(np.arange(0.001, END + 1e-9, 0.001), 6)  # every FEM–DEM step end


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    out = {}
    for seed in SEEDS:
        path, _ = packing(tmp_path_factory, n_spheres=100, seed=seed)
        fem_dem = run_fem_dem_uniform(path, fem_dem_config(n_steps=30, axial_strain=END), snapshot_interval=0)
        dstrain = increments_of(fem_dem)
        out[seed] = {
            "fem_dem": fem_dem,
            "direct_free": run_direct(DirectSpec(axial_strain=END, shear="free"), path),
            "direct_fixed": run_direct(DirectSpec(axial_strain=END), path),
            "replay_stops": run_direct(DirectSpec(mode="replay", replay_dstrain=dstrain), path),
            "replay_cont": run_direct(DirectSpec(mode="replay", replay_dstrain=dstrain, replay_stops=False), path),
        }
    return out


def _stress(result, drop_last=False):
    rows = result["records"][1:-1] if drop_last else result["records"][1:]
    return np.array([r["stress"] for r in rows])


@pytest.mark.slow
def test_a_replay_with_stops_is_the_fem_dem_rve(runs):
    """The replay mirrors Host.impose: the FEM–DEM run's committed increments, replayed on the
    packing, give its RVE stresses (so the comparisons below compare procedures, not codes)."""
    for seed, r in runs.items():
        diff = np.abs(_stress(r["replay_stops"]) - np.asarray(r["fem_dem"]["stress"])).max()
        assert diff < 1e-6, (seed, diff)


@pytest.mark.slow
def test_the_step_at_rest_between_increments_does_not_change_the_response(runs):
    """The same strain path imposed continuously (no velGrad = 0 step between increments):
    q within 0.5 % of the peak at every increment end (measured ≤ 0.08 %), the lateral stress
    still at −p within 0.5 % (measured ≤ 0.22 %)."""
    for seed, r in runs.items():
        fd = r["fem_dem"]
        s = _stress(r["replay_cont"], drop_last=True)
        q = 0.5 * (s[:, 0] + s[:, 1]) - s[:, 2]
        q_peak = peak(fd)[1]
        assert np.abs(q - np.asarray(fd["q"])).max() <= 0.005 * q_peak, seed
        assert np.abs(s[:, :2] + P0).max() <= 0.005 * P0, seed


@pytest.mark.slow
def test_fem_dem_agrees_with_the_direct_test_of_the_same_boundary_conditions(runs):
    """FEM–DEM (uniform field, smooth platens: σ11 = σ22 = −p, no shear traction) against the
    continuous direct test with the same conditions (servo on σ11, σ22 and the shear stresses):
    q within 0.85 % of the peak (measured ≤ 0.55 %) and εv within 0.02 % (measured ≤ 0.013 %)
    at every 0.1 % up to 3 %. The servo holds its stresses within 0.5 % of p."""
    for seed, r in runs.items():
        fd, direct = r["fem_dem"], r["direct_free"]
        assert direct["servo_error_max"] < 5e-3, seed
        a, b = at_strains(fd, POINTS), at_strains(direct, POINTS)
        q_peak = peak(fd)[1]
        assert np.abs(np.subtract(a["q"], b["q"])).max() <= 0.0085 * q_peak, seed
        assert np.abs(np.subtract(a["volumetric_strain"], b["volumetric_strain"])).max() <= 2e-4, seed


@pytest.mark.slow
def test_zero_shear_strain_is_another_boundary_condition(runs):
    """A periodic triaxial test that keeps the shear strains zero (the usual direct test) agrees
    with FEM–DEM before the peak, within 2.5 % of the peak q up to 2 % axial strain (measured
    ≤ 1.7 %); nearer the peak a 100-sphere RVE that may not shear is stronger (measured: up to
    2.8 % of the peak at 3 %). The FEM–DEM RVE does shear: its shear strains reach 1.8e-3 and 3.5e-3."""
    for seed, r in runs.items():
        fd, fixed = r["fem_dem"], r["direct_fixed"]
        pre = POINTS[POINTS <= 0.02]
        a, b = at_strains(fd, pre), at_strains(fixed, pre)
        assert np.abs(np.subtract(a["q"], b["q"])).max() <= 0.025 * peak(fd)[1], seed
        assert np.abs(np.asarray(fixed["records"][-1]["strain"])[3:]).max() < 1e-12, seed  # it did not shear
        assert np.abs(np.asarray(fd["strain"])[-1, 3:]).max() > 5e-4, seed
