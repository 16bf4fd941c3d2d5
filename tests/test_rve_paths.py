"""RVE paths (rule rve_paths): the strain-path families follow their definitions within their
bounds, and RVEs driven along them (real YADE, 100 spheres) give the consolidated stress at step
0, respond in the sense of the strain, resume bit for bit after a kill and report a lost contact
network as NaN with valid False."""

from __future__ import annotations

import json
import logging
import pickle
import re
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from dem_fixtures import ROOT, packing, tiny_config
from test_dem_run import _kill_after_step

from granular_multiscale.config import ConfigError, load_config, validate_config
from granular_multiscale.data import read_run
from granular_multiscale.dem.strain_paths import (
    BOUND_SLACK, FAMILIES, bounds_from_config, contraction, cost_estimate, plane_strain_frame, strain_paths_from_config,
)
from granular_multiscale.drivers.rve_paths import contact_lost, run_rve_paths
from granular_multiscale.history import history_from_sequence
from granular_multiscale.plan import Layout

P0 = 1.0e5
#: the DEM work of the default-scale runs of the latest `all` record (particle-steps per run)
DEM_WORK = {run: work["particle_steps"] for run, work in
            json.loads((ROOT / "docs" / "measured" / "all_default.json").read_text())["figures"]["dem_work"].items()}


def config_with(sets: dict, **section) -> dict:
    """The default config with these RVE-path sets and `rve_paths` keys (nested dicts merged)."""
    config = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
    config["rve_paths"] = {"sets": sets}
    # the default's RVE-path sets are not among these sets
    config["surrogate"].update(training_sources=["path1"], weak_zone_sources=[])
    for key, value in section.items():
        config["rve_paths"][key] = value
    return validate_config(config)


def paths_of(sets: dict, name: str = "s", **section):
    config = config_with(sets, **section)
    return config, strain_paths_from_config(config, name)


# ------------------------------------------------------------------------------ generator
def test_a_set_with_its_own_settings_draws_with_them_and_leaves_the_others_alone():
    """rve_paths.sets.<name>.settings replaces keys of the section for that set only: its triaxial
    trajectories go past the section's max_strain to their own, with up to their own cycle count;
    the other set is drawn as it is without the first."""
    own = {"max_strain": 0.09, "triaxial": {"cycles_min": 4, "cycles_max": 5}}
    config, long = paths_of({"s": {"triaxial": 6, "n_steps": 90, "settings": own},
                             "t": {"triaxial": 6, "n_steps": 40}})
    assert config["rve_paths"]["max_strain"] == 0.05  # the section keeps its own
    # (a triaxial trajectory designs ε33 alone: its volume is the RVE's response, not bounded)
    assert 0.05 < np.abs(long.strain[..., 2]).max() <= bounds_from_config(config, "s").max_strain == 0.09
    assert all(4 <= len(p["reversal_steps"]) // 2 <= 5 for p in long.parameters)
    other = strain_paths_from_config(config, "t").strain
    np.testing.assert_array_equal(other, paths_of({"t": {"triaxial": 6, "n_steps": 40}}, "t")[1].strain)
    assert np.abs(other[..., 2]).max() <= 0.05 + BOUND_SLACK
    for bad, message in (({"max_strain": -1.0}, "rve_paths.sets.s.settings.max_strain"),
                         ({"triaxial": {"cycle_max": 5}}, "rve_paths.sets.s.settings.triaxial"),
                         ({"sets": {}}, "unknown keys ['sets']")):
        with pytest.raises(ConfigError, match=re.escape(message)):
            config_with({"s": {"triaxial": 6, "n_steps": 90, "settings": bad}})


def test_axisymmetric_paths_follow_their_definition():
    """ε11 = ε22 = −ν ε33 exactly, no shear, |ε33| moves by exactly `increment` every step and
    turns exactly at the drawn reversal steps (1–3 unload–reload cycles), ending at its largest
    |ε33|; the last quarter of the family are extensions; ν within its range."""
    config, paths = paths_of({"s": {"axisymmetric": 40, "n_steps": 80}})
    section = config["rve_paths"]
    assert paths.strain.shape == (40, 81, 6) and set(paths.family) == {"axisymmetric"}
    senses = [p["sense"] for p in paths.parameters]
    assert senses == ["compression"] * 30 + ["extension"] * 10
    for strain, info in zip(paths.strain, paths.parameters):
        e33, nu = strain[:, 2], info["nu"]
        assert 0.2 <= nu <= 0.7
        assert np.array_equal(strain[:, 0], -nu * e33) and np.array_equal(strain[:, 1], -nu * e33)
        assert np.all(strain[:, 3:] == 0.0) and np.all(strain[0] == 0.0)
        sense = 1.0 if info["sense"] == "extension" else -1.0
        level = sense * e33  # |ε33|, never past zero to the other sense
        assert level.min() == 0.0 and level[-1] == level.max()
        step_sign = np.sign(np.diff(level))
        np.testing.assert_allclose(np.abs(np.diff(level)), section["increment"], rtol=1e-9)
        turns = [k + 1 for k in range(1, len(step_sign)) if step_sign[k] != step_sign[k - 1]]
        assert turns == info["reversal_steps"]
        assert len(turns) % 2 == 0 and 1 <= len(turns) // 2 <= 3
        peaks = level[np.asarray(turns[0::2]) - 1]
        assert np.all(np.diff(peaks) > 0) and peaks[-1] < level[-1]  # every reload goes past the last peak
    assert bounds_from_config(config).violation(paths.strain).max() <= BOUND_SLACK
    # the amplitudes reach the bounds: 4.5–5 % compression, and the dilating ν the extension bound
    assert 0.045 <= np.abs(paths.strain[:30, :, 2]).max() <= 0.05
    assert paths.strain[..., :3].sum(-1).max() > 0.9 * section["max_volumetric_extension"]


def test_proportional_paths_stay_on_their_direction():
    """ε(t) = α(t)·n at every step with α rising to its amplitude and then, for some, falling
    part way back; increments at most `increment`; amplitude within the drawn fraction of what
    the bounds allow along n."""
    config, paths = paths_of({"s": {"proportional": 30, "n_steps": 40}})
    bounds = bounds_from_config(config)
    returned = 0
    for strain, info in zip(paths.strain, paths.parameters):
        n = np.asarray(info["direction"])
        assert np.linalg.norm(n) == pytest.approx(1.0)
        alpha = strain @ n
        assert np.abs(strain - alpha[:, None] * n[None, :]).max() < 1e-15
        peak = int(np.argmax(alpha))
        assert np.all(np.diff(alpha[: peak + 1]) > 0) and np.all(np.diff(alpha[peak:]) < 0)
        assert alpha[peak] == pytest.approx(info["amplitude"])
        assert alpha[-1] >= 0.5 * alpha[peak] - 1e-15  # back part way, at most max_return_fraction
        returned += peak < 40
        # the drawn amplitude, unless `peak` increments of at most 1e-3 do not reach it
        reach = peak * 1e-3 / np.abs(n).max()
        assert min(0.3 * bounds.largest_along(n), reach) * (1 - 1e-9) <= alpha[peak] <= bounds.largest_along(n)
    assert paths.largest_increment() <= config["rve_paths"]["increment"] * (1 + 1e-12)
    assert 5 <= returned <= 25  # return_probability 0.5 of 30
    assert bounds.violation(paths.strain).max() <= BOUND_SLACK


@pytest.mark.parametrize("tight", [False, True])
def test_random_walks_take_increments_of_the_configured_size_within_the_bounds(tight):
    """Every increment's largest component is exactly `increment`; the walks reverse about
    reversal_probability of their steps; with tight bounds they reflect at them and stay inside."""
    section = ({"max_strain": 0.01, "max_shear": 0.004, "max_volumetric_extension": 0.004,
                "max_volumetric_compaction": 0.006} if tight else {})
    config, paths = paths_of({"s": {"random_walk": 20, "n_steps": 200}}, **section)
    bounds = bounds_from_config(config)
    np.testing.assert_allclose(np.abs(np.diff(paths.strain, axis=1)).max(axis=-1), 1e-3, rtol=1e-9)
    assert bounds.violation(paths.strain).max() <= BOUND_SLACK
    reversals = sum(len(p["reversal_steps"]) for p in paths.parameters)
    assert 0.02 < reversals / (20 * 199) < 0.08  # reversal_probability 0.05
    reflections = sum(p["reflections"] for p in paths.parameters)
    if tight:
        assert reflections > 100
        # they use the room they have: principal strains and shear come near their bounds
        assert np.abs(paths.strain[..., 3:]).max() > 0.9 * 0.004
    # successive increments are correlated (ρ = 0.9), not a white-noise walk
    d = np.diff(paths.strain, axis=1)
    cos = np.sum(d[:, 1:] * d[:, :-1], -1) / np.linalg.norm(d[:, 1:], axis=-1) / np.linalg.norm(d[:, :-1], axis=-1)
    assert np.median(cos) > 0.6


def test_seeded_reproducible_and_seeds_differ():
    sets = {"s": {"axisymmetric": 3, "random_walk": 3, "proportional": 3, "n_steps": 20}}
    _, a = paths_of(sets)
    _, b = paths_of(sets)
    assert np.array_equal(a.strain, b.strain) and list(a.family) == ["axisymmetric"] * 3 + ["random_walk"] * 3 + [
        "proportional"] * 3
    _, offset = paths_of({"s": {**sets["s"], "seed_offset": 1}})
    config = config_with(sets)
    config["seed"] = 5
    other_seed = strain_paths_from_config(config, "s")
    for other in (offset, other_seed):
        assert all(not np.array_equal(x, y) for x, y in zip(a.strain, other.strain))
    # each family draws from its own stream: more random walks leave the other families as they were
    _, more = paths_of({"s": {**sets["s"], "random_walk": 5}})
    assert np.array_equal(more.strain[:3], a.strain[:3]) and np.array_equal(more.strain[-3:], a.strain[-3:])
    assert np.array_equal(more.strain[3:6], a.strain[3:6])


def test_default_set_costs_at_most_half_the_fem_dem_path1_run():
    """The default-scale set: 96 trajectories x 80 steps = 7680 RVE evaluations of at most 1e-3,
    estimated within 3 % of the particle-steps the set took in the `all` record (measured: 1.3 %),
    at most half those of its FEM–DEM Path1 run."""
    config = load_config()
    cost = cost_estimate(config, strain_paths_from_config(config, "designed"))
    assert cost["trajectories"] == {"axisymmetric": 24, "random_walk": 24, "proportional": 16, "triaxial": 32,
                                    "plane_strain": 0, "isotropic_triaxial": 0}
    assert cost["n_steps"] == 80
    assert cost["rve_evaluations"] == 7680
    assert cost["largest_increment"] == pytest.approx(1e-3, rel=1e-9)
    assert cost["particle_steps_estimate"] == pytest.approx(DEM_WORK["rve_paths/designed"], rel=0.03)
    assert cost["particle_steps_estimate"] <= 0.5 * DEM_WORK["fem_dem/path1"]
    tiny = load_config(ROOT / "config" / "tiny.yaml")
    assert cost_estimate(tiny, strain_paths_from_config(tiny, "designed"))["rve_evaluations"] == 8 * 45


@pytest.mark.parametrize("sets, section, key", [
    ({"s": {"spiral": 3, "n_steps": 5}}, {}, "'rve_paths.sets.s': Additional properties are not allowed ('spiral'"),
    ({"s": {"random_walk": -1}}, {}, "'rve_paths.sets.s.random_walk': -1 is less than the minimum of 0"),
    ({"s": {"random_walk": 2}}, {"increment": -1e-3}, "'rve_paths.increment'"),
    ({"s": {"random_walk": 2}}, {"walk": {}}, "'rve_paths': Additional properties are not allowed ('walk'"),
    ({"bad-name": {"random_walk": 2}}, {}, "'rve_paths.sets': 'bad-name' does not match"),
])
def test_bad_config_is_rejected_naming_the_key(sets, section, key):
    config = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
    config["rve_paths"] = {"sets": sets, **section}
    with pytest.raises(ConfigError, match="config key " + key.replace("(", r"\(").replace(")", r"\)")):
        validate_config(config)


@pytest.mark.parametrize("sets, section, name, key", [
    ({"s": {"random_walk": 2}}, {}, "other", "'rve_paths.sets': no set named 'other'"),
    ({"s": {"n_steps": 5}}, {}, "s", "'rve_paths.sets.s': no trajectories"),
    ({"s": {"axisymmetric": 2}}, {"axisymmetric": {"nu_min": 0.6, "nu_max": 0.3}}, "s",
     "'rve_paths.axisymmetric.nu_min': 0.6 is larger than rve_paths.axisymmetric.nu_max"),
    ({"s": {"random_walk": 2}}, {"increment": 0.01, "max_shear": 0.005}, "s", "'rve_paths.increment': 0.01 does not fit"),
    ({"s": {"axisymmetric": 2, "n_steps": 400}}, {"axisymmetric": {"cycles_max": 1}}, "s",
     "'rve_paths.sets.s.n_steps': 400 axisymmetric increments"),
    ({"s": {"axisymmetric": 2, "n_steps": 3}}, {}, "s", "'rve_paths.sets.s.n_steps': 3 axisymmetric increments .* "
     "cannot be laid out"),
    ({"s": {"isotropic_triaxial": 2, "n_steps": 10}}, {}, "s", "'rve_paths.sets.s.n_steps': 0 isotropic_triaxial "
     "increments .* after 10 isotropic steps"),
    ({"s": {"isotropic_triaxial": 2}}, {"isotropic_triaxial": {"pressure_min_fraction": 2.0, "pressure_max_fraction": 1.5}},
     "s", "'rve_paths.isotropic_triaxial.pressure_min_fraction': 2.0 is larger than"),
])
def test_inconsistent_set_is_rejected_naming_the_key(sets, section, name, key):
    config = config_with(sets, **section)
    with pytest.raises(ConfigError, match="config key " + key.replace("(", r"\(")):
        strain_paths_from_config(config, name)


def test_contact_loss_criterion():
    """Lost: mean stress below 0.1 p0, or a tangent that is not positive definite (an RVE
    without contacts has a zero one); a consolidated RVE with an isotropic stiffness is not."""
    criterion = validate_config({})["rve_paths"]["contact_loss"]
    stiffness = np.diag([3e7, 3e7, 3e7, 1e7, 1e7, 1e7]) + 1e7 * np.pad(np.ones((3, 3)), (0, 3))
    stress = np.array([[-P0] * 3 + [0.0] * 3, [-0.09 * P0] * 3 + [0.0] * 3, [-P0] * 3 + [0.0] * 3])
    tangent = np.stack([stiffness, stiffness, np.zeros((6, 6))])
    lost, reasons = contact_lost(stress, tangent, P0, criterion)
    assert lost.tolist() == [False, True, True]
    assert reasons[1].startswith("mean stress 9000 Pa < 0.1 x 100000 Pa") and "not positive definite" in reasons[2]
    singular = stiffness.copy()
    singular[5, :] = singular[:, 5] = 0.0  # no stiffness against one shear
    assert contact_lost(stress[:1], singular[None], P0, criterion)[0].tolist() == [True]


def test_triaxial_trajectories_hold_their_lateral_stress(tmp_path):
    """The triaxial family: the designed part is a compression of `increment` per step with cycles;
    the servo (one evaluation per step, driven here by the elastoplastic model, whose tangent is
    exact) holds σ11 = σ22 = −f·p0 and zero shear, f drawn in its range, after the first step."""
    config = config_with({"s": {"triaxial": 3, "n_steps": 30}})
    config["reference_material"] = "elastoplastic"
    paths = strain_paths_from_config(config, "s")
    designed = paths.strain
    assert np.all(designed[..., [0, 1, 3, 4, 5]] == 0.0) and np.all(designed[..., 2] <= 0.0)
    np.testing.assert_allclose(np.abs(np.diff(designed[..., 2], axis=1)), 1e-3, rtol=1e-9)
    assert all(len(p["reversal_steps"]) >= 2 for p in paths.parameters)  # at least one unload-reload cycle
    fractions = np.array([p["lateral_stress_fraction"] for p in paths.parameters])
    assert np.all((0.7 <= fractions) & (fractions <= 1.5))
    ds = run_rve_paths(config, "s", [], tmp_path / "s.h5", None, 1)
    p0 = config["specimen"]["confining_pressure"]
    stress = ds.stress.values
    # the servo uses the last converged tangent: exact while the response stays on one branch, one step
    # behind where it turns plastic or unloads (the next step corrects the drift)
    error = np.abs(stress[1:, :, :2] + fractions[None, :, None] * p0) / (fractions[None, :, None] * p0)
    # measured: median 0.07 %, largest 9.4 % (one step, at a reversal)
    assert np.median(error) < 2e-3 and error.max() < 0.12, (np.median(error), error.max())
    assert np.abs(stress[1:, :, 3:]).max() < 1e-6 * p0
    np.testing.assert_array_equal(ds.strain.values[..., 2], designed[..., 2].T)  # the axial strain is the designed one
    assert np.all(ds.strain.values[-1, :, 0] > 0)  # the lateral strains the servo chose: the specimen bulges


def test_plane_strain_trajectories_compress_then_shear_a_band_with_their_stresses_held(tmp_path):
    """The plane-strain family, driven by the elastoplastic model (exact tangent): ε22 = ε12 = ε23 = 0
    throughout; in the compression phase ε_nn is the designed one and the servo holds σ_tt = −f·p0
    and σ_nt = 0 from the first step; in a band phase b·ε·b does not change, m·ε·b grows by the
    designed shear and m·σ·m ramps to its drawn share; a biaxial second phase goes on compressing
    along n with the same stresses held."""
    config = config_with({"s": {"plane_strain": 8, "n_steps": 40}})
    config["reference_material"] = "elastoplastic"
    paths = strain_paths_from_config(config, "s")
    ds = run_rve_paths(config, "s", [], tmp_path / "s.h5", None, 1)
    p0 = config["specimen"]["confining_pressure"]
    stress, strain = ds.stress.values, ds.strain.values
    assert np.abs(strain[..., [1, 3, 5]]).max() < 1e-15
    settings = config["rve_paths"]["plane_strain"]
    modes = [p["second_phase"] for p in paths.parameters]
    assert set(modes) == {"band", "biaxial"}, modes
    for t, p in enumerate(paths.parameters):
        n, tn, m, b = plane_strain_frame(p["axis_angle"], p["band_angle"])
        assert abs(p["axis_angle"]) <= settings["max_axis_angle"]
        assert settings["band_angle_min"] <= abs(p["band_angle"]) <= settings["band_angle_max"]
        assert settings["band_shear_min"] <= p["band_shear"] <= settings["band_shear_max"]
        k = p["compression_steps"]
        assert 0.3 * 40 - 1 <= k <= 0.5 * 40 + 1
        held = k if p["second_phase"] == "band" else 40  # the steps whose stresses across n are held
        designed = paths.strain[t]
        # ε_nn as designed: 1e-3 a step in the compression phase
        np.testing.assert_allclose(strain[:held + 1, t] @ contraction(n, n), designed[:held + 1] @ contraction(n, n),
                                   atol=1e-12)
        assert np.abs(np.diff(designed[:k + 1] @ contraction(n, n))).max() == pytest.approx(1e-3)
        lateral = np.abs(stress[1:held + 1, t] @ contraction(tn, tn) / (-p["lateral_stress_fraction"] * p0) - 1.0)
        # the last converged tangent: exact while elastic, about 1e-3 behind while hardening, one step behind
        # where the response turns (measured: median 0.1 %, 4.4 % at most, at a reversal)
        assert np.median(lateral) < 2e-3 and lateral[:k].max() < 0.08, lateral
        assert np.abs(stress[1:held + 1, t] @ contraction(n, tn)).max() < 1e-6 * p0
        if p["second_phase"] == "biaxial":  # compressed along n by the drawn total in the second phase
            assert (strain[k, t] - strain[-1, t]) @ contraction(n, n) == pytest.approx(p["band_shear"], rel=1e-9)
            # the increment grows tenfold at the switch: the stress across lags for a few steps (measured:
            # 29 % at most) and is back within 0.1 % by the end
            assert lateral[k:].max() < 0.35 and lateral[-5:].max() < 1e-3, lateral
            continue
        # band phase: b·ε·b held, m·ε·b grows by the designed shear, m·σ·m ramps from its value at the
        # switch to the drawn share of it and stays there
        np.testing.assert_allclose(strain[k:, t] @ contraction(b, b), strain[k, t] @ contraction(b, b), atol=1e-12)
        shear = (strain[-1, t] - strain[k, t]) @ contraction(m, b)
        assert shear == pytest.approx(np.sign(p["band_angle"]) * p["band_shear"], rel=1e-9)
        ratio, ramp = p["normal_stress_ratio"], p["normal_stress_ramp_steps"]
        assert settings["normal_stress_min_ratio"] <= ratio <= settings["normal_stress_max_ratio"]
        target = 1.0 + (ratio - 1.0) * np.minimum(1.0, np.arange(1, 40 - k + 1) / ramp)
        normal = stress[k + 1:, t] @ contraction(m, m) / (stress[k, t] @ contraction(m, m))
        # measured: within 1e-7 of the target at the end, 21 % off it at the first step after the switch
        assert abs(normal[-1] / target[-1] - 1.0) < 1e-3 and np.abs(normal / target - 1.0).max() < 0.3, normal
        assert strain[-1, t, :3].sum() > 0.05  # the elastoplastic model dilates in the band


# ------------------------------------------------------------------------------ real YADE
SET = {"s": {"axisymmetric": 2, "random_walk": 1, "proportional": 1, "n_steps": 6}}

RUNNER = """
import pickle, sys
from granular_multiscale.drivers.rve_paths import run_rve_paths
from granular_multiscale.runlog import setup_logging
config, packings, output, checkpoint = pickle.load(open(sys.argv[1], "rb"))
run_rve_paths(config, "s", packings, output, checkpoint, 2, logger=setup_logging(None))
"""


def dem_config(tmp_path, sets=SET, **section):
    """Tiny DEM settings (snapshots every 2 steps); by default one axisymmetric compression and one extension."""
    config = tiny_config(tmp_path / "o", {"p": [[1, 0.001]]}, snapshot_interval=2)
    config["rve_paths"] = {"sets": sets, "axisymmetric": {"extension_fraction": 0.5}, **section}
    return validate_config(config)


def _subprocess(tmp_path, config, packings, output, checkpoint):
    args = tmp_path / f"args_{Path(output).stem}.pkl"
    args.write_bytes(pickle.dumps((config, packings, str(output), str(checkpoint))))
    return subprocess.Popen([sys.executable, "-c", RUNNER, str(args)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)


@pytest.mark.needs_yade
@pytest.mark.slow
def test_rves_follow_the_strain_and_a_killed_run_resumes_bit_for_bit(tmp_path_factory, tmp_path, caplog):
    path, summary = packing(tmp_path_factory)
    packings = [str(path)]
    config = dem_config(tmp_path)
    checkpoint = tmp_path / "ck" / "a.ckpt"
    checkpoint.parent.mkdir()
    checkpoint.write_bytes(pickle.dumps({"signature": "another run", "step": 3}))
    with caplog.at_level(logging.INFO):
        a = run_rve_paths(config, "s", packings, tmp_path / "a.h5", checkpoint, 2,
                          logger=logging.getLogger("test_rve_paths"))
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "set aside" in warnings[0]
    assert not checkpoint.exists() and not (tmp_path / "ck" / "a.ckpt.scenes").exists()
    assert sum("particle-steps" in r.getMessage() and "step " in r.getMessage() for r in caplog.records) >= 6

    ds = read_run(tmp_path / "a.h5", required=("strain", "stress", "tangent"))
    paths = strain_paths_from_config(config, "s")
    assert ds.attrs["method"] == "rve_paths" and ds.attrs["rve_paths_set"] == "s"
    assert ds.sizes == {"step": 7, "gp": 4, "comp": 6, "tcomp": 21, "hist": 5}
    assert list(ds.family.values) == ["axisymmetric", "axisymmetric", "random_walk", "proportional"]
    assert np.array_equal(ds.strain.values, paths.strain.transpose(1, 0, 2))
    assert np.array_equal(ds.history.values, history_from_sequence(ds.strain.values))
    assert ds.valid.values.all() and np.all(ds.lost_contact_step.values == -1)
    assert np.isfinite(ds.stress.values).all() and np.isfinite(ds.tangent.values).all()
    # step 0: every RVE holds the consolidated packing's stress (−p0 on the diagonal)
    np.testing.assert_allclose(ds.stress.values[0], np.tile(summary["stress_voigt"], (4, 1)), rtol=1e-9, atol=1e-6)
    assert np.abs(ds.stress.values[0, :, :3] + P0).max() < 0.01 * P0
    # the stress follows the strain: compression (trajectory 0) raises |σ33| and the deviator
    # σ33 − (σ11 + σ22)/2 in its sense, extension (1) lowers both, on every loading step before the
    # first reversal; and every increment of every trajectory does positive second-order work
    assert [p["sense"] for p in paths.parameters[:2]] == ["compression", "extension"]
    stress = ds.stress.values
    for t, sense in ((0, -1.0), (1, 1.0)):
        first_turn = (paths.parameters[t]["reversal_steps"] or [7])[0]
        s = stress[:first_turn, t]
        deviator = s[:, 2] - 0.5 * (s[:, 0] + s[:, 1])
        assert first_turn >= 2 and np.all(sense * np.diff(s[:, 2]) > 0) and np.all(sense * np.diff(deviator) > 0), s
    work = np.sum(np.diff(stress, axis=0) * np.diff(ds.strain.values, axis=0) * [1, 1, 1, 2, 2, 2], axis=-1)
    assert np.all(work > 0), work
    # cost per step and in total
    assert ds.particle_steps.values[0] == 0 and np.all(ds.particle_steps.values[1:] >= 4 * 100 * 21)
    assert ds.attrs["dem_particle_steps"] == ds.particle_steps.values.sum() and ds.attrs["rve_evaluations"] == 24
    assert np.all(ds.wall_time.values[1:] > 0)

    # killed after its third step (SIGKILL of the whole process group), started again: resumes
    checkpoint = tmp_path / "ck" / "c.ckpt"
    proc = _subprocess(tmp_path, config, packings, tmp_path / "c.h5", checkpoint)
    step = _kill_after_step(proc, checkpoint, 3)
    assert 3 <= step < 6 and proc.returncode == -signal.SIGKILL, proc.stderr.read()[-2000:]
    assert not (tmp_path / "c.h5").exists()
    proc = _subprocess(tmp_path, config, packings, tmp_path / "c.h5", checkpoint)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err[-3000:]
    assert f"resuming from checkpoint {checkpoint} after step {step}" in err and "set aside" not in err
    base = 2 * (step // 2)  # the newest RVE snapshot (every 2 commits, one commit per step) + the steps since
    assert f"resumed after {step} commits (snapshot after commit {base} + {step - base} replayed" in err, err[-3000:]
    c = read_run(tmp_path / "c.h5", required=("strain", "stress", "tangent"))
    for name in ("strain", "stress", "tangent", "history", "valid", "particle_steps"):
        assert np.array_equal(c[name].values, ds[name].values), name
    assert c.attrs["dem_particle_steps"] == ds.attrs["dem_particle_steps"]


@pytest.mark.needs_yade
@pytest.mark.slow
def test_a_trajectory_that_loses_its_contacts_is_reported_and_nan(tmp_path_factory, tmp_path, caplog):
    """Isotropic extension (ν = −1, extension bound set loose) of 2e-3 per step takes one RVE's
    mean stress below 10 kPa: the warning names trajectory and step, valid is False and stress and
    tangent are NaN from that step on; the isotropic compression beside it is unaffected."""
    path, _ = packing(tmp_path_factory)
    config = dem_config(tmp_path, {"s": {"axisymmetric": 2, "n_steps": 8}}, increment=2e-3,
                        max_volumetric_extension=0.2, max_volumetric_compaction=0.05,
                        axisymmetric={"nu_min": -1.0, "nu_max": -1.0, "extension_fraction": 0.5,
                                      "cycles_min": 0, "cycles_max": 0})
    with caplog.at_level(logging.INFO):
        run_rve_paths(config, "s", [str(path)], tmp_path / "lost.h5", None, 2, logger=logging.getLogger("test_rve_paths"))
    ds = read_run(tmp_path / "lost.h5", required=("strain", "stress", "tangent"))
    strain = ds.strain.values
    assert np.array_equal(strain[:, 1, 0], strain[:, 1, 2]) and strain[-1, 1, :3].sum() == pytest.approx(0.048)
    lost = int(ds.lost_contact_step.values[1])
    assert ds.lost_contact_step.values[0] == -1 and 2 <= lost <= 8
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and f"trajectory 1 (axisymmetric) lost its contact network at step {lost}" in warnings[0]
    assert ds.valid.values[:, 0].all()
    assert ds.valid.values[:lost, 1].all() and not ds.valid.values[lost:, 1].any()
    assert np.isnan(ds.stress.values[lost:, 1]).all() and np.isnan(ds.tangent.values[lost:, 1]).all()
    assert np.isfinite(ds.stress.values[:lost, 1]).all() and np.isfinite(ds.stress.values[:, 0]).all()
    mean_stress = -ds.stress.values[:, :, :3].sum(-1) / 3
    assert mean_stress[lost - 1, 1] >= 0.1 * P0 and np.all(np.diff(mean_stress[:lost, 1]) < 0)
    assert np.all(np.diff(mean_stress[:, 0]) > 0)  # compression: the neighbour keeps stiffening
    assert ds.attrs["n_lost_contact"] == 1


@pytest.mark.needs_yade
@pytest.mark.slow
def test_plane_strain_rves_stay_plane_hold_their_stresses_and_dilate_in_the_band(tmp_path_factory, tmp_path):
    """Two plane-strain trajectories of real 100-sphere RVEs (12 steps, a band shear of 2–4 %, both
    shearing a band): the strain stays plane to round-off, the stress across the loading axis stays
    near −f·p0 in the compression phase (a contact tangent stiffer than the packing: it lags, the
    next step pulls it back), and the dense packing dilates while its band shears."""
    path, _ = packing(tmp_path_factory)
    config = dem_config(tmp_path, {"s": {"plane_strain": 2, "n_steps": 12}},
                        plane_strain={"band_shear_min": 0.02, "band_shear_max": 0.04, "cycles_max": 0,
                                      "band_probability": 1.0})
    paths = strain_paths_from_config(config, "s")
    ds = run_rve_paths(config, "s", [str(path)], tmp_path / "ps.h5", None, 2)
    strain, stress = ds.strain.values, ds.stress.values
    assert ds.valid.values.all() and np.isfinite(stress).all()
    assert np.abs(strain[..., [1, 3, 5]]).max() < 1e-15
    for t, p in enumerate(paths.parameters):
        n, tn, m, b = plane_strain_frame(p["axis_angle"], p["band_angle"])
        k = p["compression_steps"]
        lateral = stress[1:k + 1, t] @ contraction(tn, tn) / (-p["lateral_stress_fraction"] * P0)
        assert np.abs(lateral - 1.0).max() < 0.1, lateral  # measured: 1.6 % and 3.5 % at most
        assert np.all(np.diff(strain[k:, t] @ contraction(m, b)) * np.sign(p["band_angle"]) > 0)
        assert strain[-1, t, :3].sum() > strain[k, t, :3].sum() + 1e-3, strain[:, t, :3].sum(-1)  # dilates


@pytest.mark.slow
def test_rule_writes_the_set_with_log_and_benchmark(tmp_path):
    """`snakemake <out>/rve_paths/s.h5` at the tiny scale: packing, the set, its log and benchmark;
    a set name that is not configured has no rule."""
    out = tmp_path / "out"
    config = tiny_config(out, {"path1": [[1, 0.001]], "path2": [[1, 0.001]]})
    config["rve_paths"] = {"sets": {"s": {"axisymmetric": 1, "random_walk": 1, "proportional": 1, "n_steps": 4}}}
    config_file = tmp_path / "config.yaml"
    config_file.write_text(yaml.safe_dump(validate_config(config)))
    snakemake = str(Path(sys.executable).with_name("snakemake"))
    command = [snakemake, "-j2", "--configfile", str(config_file), "--"]
    L = Layout(out)
    missing = subprocess.run([*command[:1], "-n", *command[1:], L.rve_paths("other")], cwd=ROOT,
                             capture_output=True, text=True, timeout=300)
    assert missing.returncode != 0 and "MissingRuleException" in missing.stdout + missing.stderr
    result = subprocess.run([*command, L.rve_paths("s")], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-4000:]
    ds = read_run(L.rve_paths("s"), required=("strain", "stress", "tangent"))
    assert ds.sizes["gp"] == 3 and ds.sizes["step"] == 5 and np.isfinite(ds.stress.values).all()
    log = Path(L.log("rve_paths/s")).read_text()
    assert log.count("particle-steps") == 5 and "rve_paths s: done" in log and "12 RVE evaluations" in log
    assert Path(L.benchmark("rve_paths/s")).exists()
    assert not Path(L.checkpoint("rve_paths/s")).exists()
