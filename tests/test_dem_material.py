"""DemMaterialPointSet against the RVEs themselves: conventions, tangent, rollback, state."""

from __future__ import annotations

import numpy as np
import pytest
from dem_fixtures import SETTINGS, packing

from granular_multiscale.dem.executors import HostError
from granular_multiscale.dem.material import DemMaterialPointSet, packing_assignment
from granular_multiscale.dem.worker import steps_for_increment
from granular_multiscale.materials.base import MaterialPointError
from granular_multiscale.tensors import engineering

P0 = 1.0e5
pytestmark = [pytest.mark.slow, pytest.mark.needs_yade]  # every test here runs YADE


def _material(path, n_points=1, n_workers=1, settings=None, **kw) -> DemMaterialPointSet:
    return DemMaterialPointSet(n_points, [path], settings or SETTINGS, n_workers=n_workers, **kw)


# an increment imposed in one DEM step (+ one at rest): affine, no time to slide or rearrange
ONE_STEP = dict(SETTINGS, strain_rate=1e9, min_steps=1)


def _response(m: DemMaterialPointSet, magnitude: float) -> tuple[np.ndarray, np.ndarray]:
    """Stress change of points 0–5 under `magnitude` along each Voigt direction (tensorial
    strain), minus that of point 6, which gets a negligible increment: what the packing does
    in two steps anyway (it was consolidated to an unbalanced force of ~1e-3, not zero)."""
    de = np.zeros((7, 6))
    de[:6] = magnitude * np.eye(6)
    de[6, 0] = 1e-15
    stress, _ = m.evaluate(de)
    change = stress - m.conv_stress
    return change[:6] - change[6], de[:6]


def test_steps_for_increment():
    dt = 2e-6
    assert steps_for_increment(np.zeros(6), dt, 2.5, 20, 1000) == 0
    assert steps_for_increment(np.array([0, 0, -0.999e-3, 0, 0, 0]), dt, 2.5, 20, 1000) == 200  # ceil(199.8)
    assert steps_for_increment(np.array([0, 0, 0, 0, 1e-8, 0]), dt, 2.5, 20, 1000) == 20
    assert steps_for_increment(np.array([0.1, 0, 0, 0, 0, 0]), dt, 2.5, 20, 1000) == 1000


def test_tangent_is_engineering_voigt_and_exact_for_frictionless_contacts(tmp_path_factory):
    """YADE's getStressAndTangent tangent D acts on the engineering strain, as tensors.py wants.

    With μ = 0 the contacts carry no tangential force, so the contact-stiffness tangent is the
    whole small-strain stiffness of the packing. A tiny increment (1e-6) imposed in one DEM step
    (plus one at rest) is affine: no sliding, no rearrangement. Then Δσ = D · eng(Δε) within 5 %
    for each of the six Voigt directions; reading D as acting on tensorial strain would be off by
    a factor 2 in the three shear columns."""
    path, _ = packing(tmp_path_factory, friction=0.0)
    with _material(path, n_points=7, settings=ONE_STEP) as m:
        D = m.conv_tangent[0]
        assert np.allclose(m.conv_tangent, D)  # one packing shared by all points
        ds, de = _response(m, 1e-6)
    for j in range(6):
        predicted = D @ engineering(de[j])
        assert np.linalg.norm(ds[j] - predicted) <= 0.05 * np.linalg.norm(predicted), j
        tensorial = D @ de[j]
        if j >= 3:
            assert np.linalg.norm(ds[j] - tensorial) > 0.5 * np.linalg.norm(tensorial)


def test_tangent_of_the_frictional_rve_is_a_lower_bound(tmp_path_factory):
    """With μ = 0.5 restored, contacts resist sliding with the Mindlin tangential stiffness, but
    YADE's tangent counts k_t only along a contact's current shear force, and right after the
    frictionless consolidation no contact has one: the RVE is stiffer than D predicts. Recorded
    here so nobody mistakes it for a convention error: the response still points the way D says
    (cosine > 0.9) and is 1.1–1.6 × as large (this packing: ≈ 1.2× along normal, ≈ 1.35× along
    shear directions; the frictionless check above agrees within 2 %)."""
    path, _ = packing(tmp_path_factory)
    with _material(path, n_points=7, settings=ONE_STEP) as m:
        D = m.conv_tangent[0]
        ds, de = _response(m, 1e-6)
    for j in range(6):
        predicted = D @ engineering(de[j])
        ratio = ds[j] @ predicted / (predicted @ predicted)
        cosine = ds[j] @ predicted / np.linalg.norm(ds[j]) / np.linalg.norm(predicted)
        assert 1.1 <= ratio <= 1.6 and cosine > 0.9, (j, ratio, cosine)


def test_signs_initial_state_and_response(tmp_path_factory):
    """Tension positive everywhere: the consolidated RVE reads −p0; stretching raises σ,
    compressing lowers it; the increment runs at the configured strain rate."""
    path, summary = packing(tmp_path_factory)
    with _material(path, n_points=2) as m:
        assert np.allclose(m.conv_stress, summary["stress_voigt"], rtol=0, atol=1e-6 * P0)
        assert np.abs(m.conv_stress[:, :3] + P0).max() < 0.01 * P0
        de = np.zeros((2, 6))
        de[0, 2], de[1, 2] = -5e-4, 5e-4
        stress, tangent = m.evaluate(de)
        assert stress[0, 2] < m.conv_stress[0, 2] < stress[1, 2]
        assert tangent.shape == (2, 6, 6) and np.all(np.diag(tangent[0]) > 0)
        n = steps_for_increment(de[0], summary["timestep"], SETTINGS["strain_rate"], SETTINGS["min_steps"], SETTINGS["max_steps"])
        assert m._step["trials"] == 1 and m._step["dem_steps_max"] == n > SETTINGS["min_steps"]
        assert m._step["particle_steps"] == 2 * (n + 1) * summary["n_spheres"]  # + the step at rest


def test_rollback_and_commit(tmp_path_factory):
    """Trials start from the converged state; commit continues from the accepted trial."""
    path, _ = packing(tmp_path_factory)
    rng = np.random.default_rng(1)
    a = rng.normal(scale=3e-4, size=(3, 6))
    b = a + rng.normal(scale=1e-4, size=(3, 6))
    with _material(path, n_points=3, n_workers=2) as m, _material(path, n_points=3) as fresh:
        sa, ta = m.evaluate(a)
        sb, _ = m.evaluate(b)
        sa2, ta2 = m.evaluate(a.copy() + 0.0)
        assert not np.array_equal(sa, sb)
        assert np.array_equal(sa, sa2) and np.array_equal(ta, ta2)  # the same trial, bit for bit
        m.evaluate(b)  # the last trial before commit is b
        m.commit()
        assert m.step_info()["trials"] == 4  # a, b, a, b: a repeated trial is recomputed, not remembered
        assert np.array_equal(m.conv_stress, sb)
        # a repeat of the very last trial is answered without the RVEs
        fresh.evaluate(a)
        before = dict(fresh._step)
        fresh.evaluate(a.copy())
        assert fresh._step["trials"] == before["trials"]


def test_commit_continues_from_the_accepted_trial(tmp_path_factory):
    path, _ = packing(tmp_path_factory)
    rng = np.random.default_rng(2)
    a = rng.normal(scale=3e-4, size=(2, 6))
    c = a + rng.normal(scale=3e-4, size=(2, 6))
    with _material(path, n_points=2) as m, _material(path, n_points=2) as other:
        m.evaluate(rng.normal(scale=1e-3, size=(2, 6)))  # a rejected trial first
        sa, _ = m.evaluate(a)
        m.commit()
        assert np.array_equal(m.conv_stress, sa) and np.array_equal(m.conv_strain, a)
        # zero increment from the new converged state: the converged answer, no DEM steps
        s0, _ = m.evaluate(a.copy())
        assert np.array_equal(s0, sa)
        sc, _ = m.evaluate(c)
        # the same two increments on a set that never saw the rejected trial
        other.evaluate(a)
        other.commit()
        sc_other, _ = other.evaluate(c)
        assert np.array_equal(sc, sc_other) and not np.array_equal(sc, sa)


def test_commit_at_an_earlier_trial_strain(tmp_path_factory):
    """commit(a) after a later trial b (a line search that kept an earlier length): the RVEs
    continue from the state at a, bit for bit like a set whose last trial was a."""
    path, _ = packing(tmp_path_factory)
    rng = np.random.default_rng(4)
    a = rng.normal(scale=3e-4, size=(2, 6))
    b = a + rng.normal(scale=2e-4, size=(2, 6))
    c = a + rng.normal(scale=3e-4, size=(2, 6))
    with _material(path, n_points=2) as m, _material(path, n_points=2) as direct:
        sa, _ = m.evaluate(a)
        m.evaluate(b)
        m.commit(a)
        assert np.array_equal(m.conv_strain, a) and np.array_equal(m.conv_stress, sa)
        direct.evaluate(a)
        direct.commit(a)
        assert np.array_equal(m.evaluate(c)[0], direct.evaluate(c)[0])


def test_results_do_not_depend_on_the_number_of_workers(tmp_path_factory):
    path, _ = packing(tmp_path_factory)
    strain = np.random.default_rng(3).normal(scale=5e-4, size=(5, 6))
    answers = []
    for workers in (1, 2, 3):
        with _material(path, n_points=5, n_workers=workers) as m:
            assert len(m.slots) == workers
            m.evaluate(strain)
            m.commit()
            answers.append(m.evaluate(2 * strain))
    for s, t in answers[1:]:
        assert np.array_equal(s, answers[0][0]) and np.array_equal(t, answers[0][1])


@pytest.mark.parametrize("with_snapshots", [False, True])
def test_state_round_trip_replays_bit_for_bit(tmp_path_factory, tmp_path, with_snapshots):
    path, _ = packing(tmp_path_factory)
    rng = np.random.default_rng(4)
    strains = np.cumsum(rng.normal(scale=4e-4, size=(5, 3, 6)), axis=0)
    snap = dict(snapshot_dir=tmp_path / "scenes", snapshot_interval=2) if with_snapshots else {}
    with _material(path, n_points=3, n_workers=2, **snap) as m:
        for k in range(3):
            m.evaluate(strains[k] * 1.1)  # a rejected trial
            m.evaluate(strains[k])
            m.commit()
        state = m.get_state()
        reference = [m.evaluate(strains[3]), None]
        m.commit()
        reference[1] = m.evaluate(strains[4])
    assert state["commits"] == 3
    if with_snapshots:
        assert state["base"]["step"] == 2 and len(state["replay"]) == 1
        assert all((tmp_path / "scenes").joinpath(f"commit00002_slot{j}.pkl").exists() for j in range(2))
    else:
        assert state["base"] is None and len(state["replay"]) == 3
    # a new set (another worker count) resumes from the state and continues identically
    with _material(path, n_points=3, n_workers=1, **snap) as resumed:
        resumed.set_state(state)
        assert np.array_equal(resumed.conv_stress, state["converged_stress"])
        s3, t3 = resumed.evaluate(strains[3])
        resumed.commit()
        s4, t4 = resumed.evaluate(strains[4])
    assert np.array_equal(s3, reference[0][0]) and np.array_equal(t3, reference[0][1])
    assert np.array_equal(s4, reference[1][0]) and np.array_equal(t4, reference[1][1])


def test_state_from_other_packing_or_settings_is_refused(tmp_path_factory):
    path, _ = packing(tmp_path_factory)
    other, _ = packing(tmp_path_factory, friction=0.0)
    with _material(path) as m:
        state = m.get_state()
    with _material(other) as m2, pytest.raises(ValueError, match="changed"):
        m2.set_state(state)
    with _material(path, settings=dict(SETTINGS, strain_rate=1.0)) as m3, pytest.raises(ValueError, match="settings"):
        m3.set_state(state)


def test_bad_input_and_dead_workers_are_errors(tmp_path_factory, tmp_path):
    path, _ = packing(tmp_path_factory)
    with pytest.raises(FileNotFoundError, match="nowhere"):
        _material(tmp_path / "nowhere.yade.gz")
    with pytest.raises(ValueError, match="strain_rate"):
        DemMaterialPointSet(1, [path], {"damping": 0.2})
    with _material(path, n_points=4, n_workers=2) as m:
        with pytest.raises(ValueError, match=r"\[4, 6\]"):
            m.evaluate(np.zeros((3, 6)))
        bad = np.zeros((4, 6))
        bad[2, 0] = np.nan
        with pytest.raises(MaterialPointError, match=r"Gauss points \[2\]"):
            m.evaluate(bad)
        # a worker killed from outside: the next evaluation fails loudly, naming it
        import os
        import signal

        os.killpg(m.executor.hosts[1][0].pid, signal.SIGKILL)
        with pytest.raises(HostError, match="worker 1"):
            m.evaluate(np.full((4, 6), 1e-5))


def test_packing_assignment():
    assert np.array_equal(packing_assignment(5, 1, 0), np.zeros(5))
    a = packing_assignment(200, 3, 7)
    assert set(a.tolist()) == {0, 1, 2} and np.array_equal(a, packing_assignment(200, 3, 7))
