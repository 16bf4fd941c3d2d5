"""Newton solver: quadratic convergence, cutbacks, FE vs point-wise material, checkpoint/resume."""

import logging
import time

import numpy as np
import pytest
from conftest import KilledAfterCommits

from granular_multiscale.fem.newton import ConvergenceError, NewtonSettings
from granular_multiscale.fem.triaxial import TriaxialProblem
from granular_multiscale.materials import Elastoplastic, LinearElastic, MaterialPointError
from granular_multiscale.materials.elastoplastic import REVERSE_YIELDING
from granular_multiscale.paths import LoadPath

PATH2 = LoadPath("path2", ((9, 0.009), (6, 0.003), (42, 0.045)))
SHORT = LoadPath("short", ((4, 0.008), (3, 0.002), (3, 0.01)))


def relative_residuals(ds):
    return ds.residual_norm.values / ds.residual_reference.values[:, None]


def test_newton_converges_quadratically_with_consistent_tangent():
    problem = TriaxialProblem(size=(0.5, 0.5, 1.0), elements=(2, 2, 4), platen="rough")
    ds = problem.run(Elastoplastic(problem.n_gauss_points, initial_stress=problem.initial_stress), PATH2,
                     progress=False)
    assert ds.cutbacks.values.sum() == 0
    rel = relative_residuals(ds)
    ratios = []
    for k in range(1, rel.shape[0]):
        e = rel[k][np.isfinite(rel[k])]
        for a, b in zip(e[:-1], e[1:]):
            if 1e-12 < a < 1e-2 and b > 1e-14:  # asymptotic range, above round-off
                ratios.append(b / a**2)
        if k in (1, 10, 16, 30):
            print(f"step {k:2d} relative residuals: " + "  ".join(f"{x:.2e}" for x in e))
    ratios = np.array(ratios)
    print("e_(k+1)/e_k^2:", np.array2string(ratios, precision=3))
    assert ratios.size >= 10
    assert ratios.max() < 10.0  # quadratic: e_{k+1} <= C e_k^2
    assert ds.newton_iterations.values.max() <= 4
    assert np.all(np.nanmin(rel, axis=1) <= 1e-8)


class ElasticTangentElastoplastic(Elastoplastic):
    """The same model with the elastic (not consistent) tangent: Newton must slow down."""

    def evaluate(self, strain, need_tangent=True):
        stress, _ = super().evaluate(strain, need_tangent=False)
        return stress, np.broadcast_to(self.elastic_tangent, (self.n_points, 6, 6)).copy()


def test_inconsistent_tangent_converges_only_linearly():
    problem = TriaxialProblem(elements=(2, 2, 4), newton=NewtonSettings(max_iterations=200))
    consistent = problem.run(Elastoplastic(problem.n_gauss_points, initial_stress=problem.initial_stress), SHORT,
                             progress=False)
    elastic = problem.run(ElasticTangentElastoplastic(problem.n_gauss_points, initial_stress=problem.initial_stress),
                          SHORT, progress=False)
    print("iterations consistent", consistent.newton_iterations.values, "elastic", elastic.newton_iterations.values)
    assert elastic.newton_iterations.values.sum() > 3 * consistent.newton_iterations.values.sum()
    # both solve the same problem
    np.testing.assert_allclose(elastic.stress.values, consistent.stress.values, rtol=0, atol=1e-3 * 1e5)


def test_fe_gauss_point_equals_point_wise_model_on_homogeneous_run():
    """Smooth platens: the specimen deforms homogeneously, and the stresses at the Gauss
    points equal the model driven point-wise through the same strain sequence."""
    problem = TriaxialProblem(size=(0.5, 0.5, 1.0), elements=(2, 2, 2), platen="smooth")
    path = LoadPath("loop", ((5, 0.01), (4, 0.002), (5, 0.02)))
    ds = problem.run(Elastoplastic(problem.n_gauss_points, **REVERSE_YIELDING, initial_stress=problem.initial_stress),
                     path, progress=False)
    assert ds.cutbacks.values.sum() == 0
    strain = ds.strain.values
    np.testing.assert_allclose(strain, np.broadcast_to(strain[:, :1], strain.shape), atol=1e-13)  # homogeneous
    point = Elastoplastic(1, **REVERSE_YIELDING, initial_stress=problem.initial_stress)
    for k in range(strain.shape[0]):
        stress, D = point.evaluate(strain[k, :1])
        point.commit()
        np.testing.assert_allclose(ds.stress.values[k], np.broadcast_to(stress, (problem.n_gauss_points, 6)),
                                   rtol=0, atol=1e-6 * 1e5)
    # the unloading went plastic in reverse and the loop dissipates
    q = -ds.top_force.values / 0.25 - 1e5
    assert (ds.plastic_fraction.values[ds.phase.values == "unloading"] > 0).any()
    assert q[5] > 1.0e5 and q[9] < 0  # unloaded from >100 kPa into extension


class FailsBeyondIncrement(LinearElastic):
    """Linear elastic points that refuse trial strains too far from the converged ones,
    like an RVE that blows up on a large increment: forces cutbacks."""

    def __init__(self, *args, limit, **kwargs):
        super().__init__(*args, **kwargs)
        self.limit = limit

    def evaluate(self, strain, need_tangent=True):
        jump = np.abs(np.asarray(strain) - self._converged_strain).max(axis=1)
        if np.any(jump > self.limit):
            raise MaterialPointError(f"increment too large at Gauss points {np.flatnonzero(jump > self.limit)[:3]}")
        return super().evaluate(strain, need_tangent)


def test_cutbacks_halve_the_step_and_reach_the_same_state():
    problem = TriaxialProblem(elements=(1, 1, 2), platen="smooth")
    path = LoadPath("p", ((2, 0.004),))  # increments of 0.2 %
    reference = problem.run(LinearElastic(16, 5e7, 0.25, initial_stress=problem.initial_stress), path,
                            progress=False)
    cut = problem.run(FailsBeyondIncrement(16, 5e7, 0.25, initial_stress=problem.initial_stress, limit=0.0006),
                      path, progress=False)
    # 0.2 % fails, 0.1 % fails, 0.05 % passes: 2 halvings on the first try, then the other halves
    assert cut.cutbacks.values[0] == 0 and cut.cutbacks.values[1] >= 2
    np.testing.assert_allclose(cut.stress.values, reference.stress.values, rtol=0, atol=1e-9 * 1e5)
    np.testing.assert_allclose(cut.top_force.values, reference.top_force.values, rtol=1e-12)


def test_step_that_never_converges_names_the_load_step():
    problem = TriaxialProblem(elements=(1, 1, 2), platen="smooth", newton=NewtonSettings(max_cutbacks=2))
    path = LoadPath("p", ((1, 0.0004), (1, 0.01)))
    material = FailsBeyondIncrement(16, 5e7, 0.25, initial_stress=problem.initial_stress, limit=0.0006)
    with pytest.raises(ConvergenceError, match=r"load step 2 .* after 2 cutbacks"):
        problem.run(material, path, progress=False)


class KilledAfter(KilledAfterCommits, Elastoplastic):
    pass


def test_checkpoint_resume_gives_the_uninterrupted_result(tmp_path, caplog):
    problem = TriaxialProblem(elements=(2, 2, 2), platen="rough")
    checkpoint = tmp_path / "run.ckpt"
    full = problem.run(Elastoplastic(problem.n_gauss_points, initial_stress=problem.initial_stress), SHORT,
                       progress=False)

    killed = KilledAfter(problem.n_gauss_points, initial_stress=problem.initial_stress, commits=6)
    with pytest.raises(KeyboardInterrupt):
        problem.run(killed, SHORT, checkpoint=checkpoint, progress=False)
    assert checkpoint.exists()

    with caplog.at_level(logging.INFO, logger="granular_multiscale.fem"):
        resumed = problem.run(Elastoplastic(problem.n_gauss_points, initial_stress=problem.initial_stress), SHORT,
                              checkpoint=checkpoint, progress=True)
    assert "resuming from checkpoint" in caplog.text and "after step 5" in caplog.text
    assert "step   5/" not in caplog.text and "step   6/" in caplog.text  # steps 0-5 were not recomputed
    assert not checkpoint.exists()
    for name in full.data_vars:
        if name != "wall_time":
            np.testing.assert_array_equal(resumed[name].values, full[name].values, err_msg=name)


def test_checkpoint_of_another_run_is_ignored(tmp_path, caplog):
    problem = TriaxialProblem(elements=(1, 1, 2))
    checkpoint = tmp_path / "run.ckpt"
    killed = KilledAfter(16, initial_stress=problem.initial_stress, commits=3)
    with pytest.raises(KeyboardInterrupt):
        problem.run(killed, SHORT, checkpoint=checkpoint, progress=False)
    other_path = LoadPath("other", ((5, 0.01),))
    with caplog.at_level(logging.WARNING, logger="granular_multiscale.fem"):
        ds = problem.run(Elastoplastic(16, initial_stress=problem.initial_stress), other_path, checkpoint=checkpoint,
                         progress=False)
    assert "belongs to another run" in caplog.text
    assert ds.sizes["step"] == 6


def test_material_size_must_match_mesh():
    problem = TriaxialProblem(elements=(1, 1, 2))
    with pytest.raises(ValueError, match="material set has 8 points, the mesh 16 Gauss points"):
        problem.run(LinearElastic(8, 5e7, 0.2), SHORT, progress=False)


def test_anderson_mixing_refuses_a_non_finite_correction():
    """A diverged iterate (inf/NaN correction) must fail the step cleanly — so the solver cuts the
    step back or stops naming it — and never reach the least-squares solve as NaN."""
    from granular_multiscale.fem.newton import StepFailed, _Anderson

    free = np.arange(4)
    mixer = _Anderson(free, depth=3)
    u = np.zeros(4)
    first = mixer.step(u, np.array([1.0, 0.5, 0.0, 0.0]))
    np.testing.assert_array_equal(first, [1.0, 0.5, 0.0, 0.0])  # no history yet: the plain correction
    with pytest.raises(StepFailed, match="non-finite Newton correction"):
        mixer.step(u + first, np.array([np.inf, 0.0, np.nan, 0.0]))


class RecordsCommits(Elastoplastic):
    """Remembers the strain every commit was given, and the strain of the last evaluation."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.committed, self.last_evaluated = [], []

    def evaluate(self, strain, need_tangent=True):
        self.last = np.array(strain)
        return super().evaluate(strain, need_tangent)

    def commit(self, strain=None):
        self.committed.append(None if strain is None else np.array(strain))
        self.last_evaluated.append(self.last.copy())
        super().commit(strain)


def test_the_solver_commits_the_strain_it_accepted():
    """The converged state is named explicitly: every commit gets the strain the run file records
    for that step (with a line search the accepted trial need not be the last one evaluated)."""
    problem = TriaxialProblem(elements=(1, 1, 2), platen="rough", newton=NewtonSettings(line_search=True))
    material = RecordsCommits(problem.n_gauss_points, initial_stress=problem.initial_stress)
    ds = problem.run(material, SHORT, progress=False)
    assert len(material.committed) == ds.sizes["step"] and not ds.cutbacks.values.any()
    for step, strain in enumerate(material.committed):
        assert strain is not None, f"step {step}: commit() without the accepted strain"
        np.testing.assert_array_equal(strain, ds.strain.values[step])


def test_commit_at_an_earlier_trial_equals_committing_that_trial():
    """commit(strain) after a later evaluation elsewhere: the set goes back to the state at `strain`."""
    e1 = np.tile([0.004, 0.004, -0.01, 0.0, 0.0, 0.0], (2, 1))  # beyond first yield
    e2 = 1.5 * e1
    direct = Elastoplastic(2, initial_stress=[-1e5, -1e5, -1e5, 0, 0, 0])
    direct.evaluate(e1)
    direct.commit(e1)
    detour = Elastoplastic(2, initial_stress=[-1e5, -1e5, -1e5, 0, 0, 0])
    detour.evaluate(e1)
    detour.evaluate(e2)  # e.g. a rejected line-search length, evaluated after the accepted one
    detour.commit(e1)
    a, b = direct.get_state(), detour.get_state()
    assert a["kappa"].max() > 0  # plastic: the committed state carries history
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


class SlowElastoplastic(Elastoplastic):
    """Elastoplastic points whose every evaluation takes 5 ms more, so wall times are measurable."""

    def evaluate(self, strain, need_tangent=True):
        import time

        time.sleep(0.005)
        return super().evaluate(strain, need_tangent)


class SlowKilledAfter(KilledAfter, SlowElastoplastic):
    pass


def test_a_resumed_run_counts_the_time_of_the_steps_before_its_checkpoint(tmp_path):
    problem = TriaxialProblem(elements=(1, 1, 2), platen="rough")
    checkpoint = tmp_path / "run.ckpt"
    n = problem.n_gauss_points
    full = problem.run(SlowElastoplastic(n, initial_stress=problem.initial_stress), SHORT, progress=False)
    with pytest.raises(KeyboardInterrupt):
        problem.run(SlowKilledAfter(n, initial_stress=problem.initial_stress, commits=6), SHORT,
                    checkpoint=checkpoint, progress=False)
    resumed = problem.run(SlowElastoplastic(n, initial_stress=problem.initial_stress), SHORT,
                          checkpoint=checkpoint, progress=False)
    steps = resumed.wall_time.values
    before = steps[:6].sum()
    assert before > 0.3 * steps.sum()  # the checkpoint holds a good share of the run
    # the run's time is that of all its load steps, not only of those after the resume
    assert resumed.attrs["time_run_s"] >= steps.sum()
    # every evaluation, before the checkpoint or after it, sleeps 5 ms: a floor that holds on a
    # loaded machine too (against the full run's wall time, the ratio varies with the load)
    assert resumed.attrs["time_run_s"] >= 0.005 * full.attrs["total_material_evaluations"]
    assert resumed.attrs["time_resume_s"] >= 0 and full.attrs["time_resume_s"] == 0
    for key in ("total_newton_corrections", "total_material_evaluations", "total_tangent_evaluations"):
        assert resumed.attrs[key] == full.attrs[key], key
    assert resumed.attrs["time_material_s"] >= 0.005 * full.attrs["total_material_evaluations"]


def test_the_run_time_is_that_of_the_load_steps_not_of_writing_the_dataset(monkeypatch):
    """time_run_s (the speedup table's wall time) counts the load steps; building the run's Dataset,
    which imports dask on a process's first xarray Variable, is not one of them."""
    from granular_multiscale.fem.recorder import RunRecorder

    problem = TriaxialProblem(elements=(1, 1, 2), platen="rough")
    build = RunRecorder.dataset

    def slow_build(self, *args, **kwargs):
        time.sleep(0.5)
        return build(self, *args, **kwargs)

    monkeypatch.setattr(RunRecorder, "dataset", slow_build)
    ds = problem.run(Elastoplastic(problem.n_gauss_points, initial_stress=problem.initial_stress), SHORT,
                     progress=False)
    steps = float(ds.wall_time.values.sum())
    # between the steps only the recording and the log line run: well under the half second slept
    assert steps <= ds.attrs["time_run_s"] < steps + 0.25


class KeyedElastoplastic(Elastoplastic):
    """Elastoplastic points whose converged state depends on a setting (like a DEM packing)."""

    def __init__(self, *args, key="a", refuse=False, **kwargs):
        super().__init__(*args, **kwargs)
        self.key, self.refuse = key, refuse

    def checkpoint_key(self):
        return {"setting": self.key}

    def set_state(self, state):
        if self.refuse:
            raise ValueError("packing changed since the checkpoint was written")
        super().set_state(state)


class KeyedKilledAfter(KilledAfter, KeyedElastoplastic):
    pass


@pytest.mark.parametrize("change", ["key", "refused"])
def test_a_checkpoint_that_no_longer_matches_its_run_is_set_aside(tmp_path, caplog, change):
    """A config change between a kill and the rerun (other DEM settings or packings): one log line,
    the stale checkpoint is removed and the run starts afresh, with the uninterrupted result."""
    problem = TriaxialProblem(elements=(1, 1, 2), platen="rough")
    checkpoint = tmp_path / "run.ckpt"
    n, p0 = problem.n_gauss_points, problem.initial_stress
    with pytest.raises(KeyboardInterrupt):
        problem.run(KeyedKilledAfter(n, initial_stress=p0, commits=4), SHORT, checkpoint=checkpoint, progress=False)
    assert checkpoint.exists()
    changed = KeyedElastoplastic(n, initial_stress=p0, key="b") if change == "key" else \
        KeyedElastoplastic(n, initial_stress=p0, refuse=True)
    with caplog.at_level(logging.INFO, logger="granular_multiscale.fem"):
        ds = problem.run(changed, SHORT, checkpoint=checkpoint, progress=False)
    warnings = [r for r in caplog.records if "set aside" in r.getMessage()]
    assert len(warnings) == 1 and warnings[0].levelno == logging.WARNING
    assert "resuming" not in caplog.text
    if change == "refused":
        assert "packing changed" in warnings[0].getMessage()
    fresh = problem.run(KeyedElastoplastic(n, initial_stress=p0, key="b"), SHORT, progress=False)
    for name in ("strain", "stress", "top_force"):
        np.testing.assert_array_equal(ds[name].values, fresh[name].values, err_msg=name)
    assert not checkpoint.exists()


class ElasticTangentElastoplastic(Elastoplastic):
    """Elastoplastic stresses with the elastic tangent, stiffer than the response once it yields:
    like YADE's contact-stiffness tangent, which ignores sliding."""

    def evaluate(self, strain, need_tangent=True):
        stress, tangent = super().evaluate(strain, need_tangent)
        if tangent is not None:
            tangent = np.broadcast_to(self.elastic_tangent, tangent.shape).copy()
        return stress, tangent


def test_extrapolating_predictor_saves_corrections_with_a_stiff_tangent():
    """predictor: extrapolate starts a step from the last converged increment scaled to this one.
    With a tangent that is too stiff (the DEM case) and FEM–DEM's kind of tolerance it needs far
    fewer corrections than the tangent predictor on Path2, and the converged states agree within
    that tolerance; at the two reversals it falls back to the tangent predictor. (With the
    consistent tangent the tangent predictor is better: 2 corrections on this path, 28 with
    extrapolation.)"""
    results = {}
    for predictor in ("tangent", "extrapolate"):
        problem = TriaxialProblem(elements=(1, 1, 2), platen="rough",
                                  newton=NewtonSettings(tolerance=1e-3, max_iterations=200, predictor=predictor))
        material = ElasticTangentElastoplastic(problem.n_gauss_points, initial_stress=problem.initial_stress)
        results[predictor] = problem.run(material, PATH2, progress=False)
    tangent, extrapolate = results["tangent"], results["extrapolate"]
    assert extrapolate.newton_iterations.values.sum() < 0.6 * tangent.newton_iterations.values.sum()
    assert (extrapolate.residual_relative.values <= 1e-3).all()
    peak = np.abs(tangent.top_force.values).max()
    assert np.abs(extrapolate.top_force.values - tangent.top_force.values).max() < 2e-3 * peak
    # the first step of each monotonic segment has no increment to extrapolate in its direction:
    # the same predictor, the same corrections
    for step in (1, 10, 16):
        assert extrapolate.newton_iterations.values[step] == tangent.newton_iterations.values[step], step
    with pytest.raises(ValueError, match="newton.predictor"):
        NewtonSettings(predictor="linear")
