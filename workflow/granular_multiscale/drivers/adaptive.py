"""Adaptive FEM–DEM–ML runs: the FEM solver of any problem with :class:`AdaptiveMaterialPointSet` at the
Gauss points (the surrogate where it is sure, a YADE RVE where it is not; ``adaptive/material.py``).

    run_adaptive(config, path_name, threshold, packing_paths, sigma_model, tangent_model, tangent,
                 output, checkpoint, n_workers, logger)

Settings: the section ``adaptive`` (indicator, out_of_range_weight, anchor_fraction; the threshold is
an argument, one run per entry of ``adaptive.thresholds``), the RVEs and DEM settings of ``dem``, the
networks and ``surrogate`` settings of FEM–ML. Newton: FEM–DEM's (``newton`` with the ``dem.newton``
overrides, :func:`dem_newton_config`): the answers that matter are DEM answers, noisy at the level
FEM–DEM's tolerance was chosen for. With those settings threshold ∞ is the FEM–ML run and
threshold 0 (or ``anchor_fraction`` 1) the FEM–DEM run, bit for bit (tests/test_adaptive.py).

The run file is in the data contract, with FEM–DEM's per-step DEM time split, FEM–ML's
``stress_spread``/``stress_spread_relative`` (the surrogate answers at every point; relative to the
run's stress, DEM where the point is DEM) and (:func:`adaptive_variables`):

* ``point_mode(step, gp)``: 1 where the point answered from its RVE at the step's converged state;
* ``indicator(step, gp)``: the promotion indicator at the converged strain (what was compared with
  the threshold);
* per load step, summed over its commits (cut-back sub-steps included): ``promotions``,
  ``particle_steps`` (DEM trials), ``replay_particle_steps``, ``replay_time``, the time split;
  ``dem_points`` and ``correction`` (mean norm of the correction at the surrogate points, Pa) at its end;
* attributes ``adaptive_threshold``, ``adaptive_indicator``, ``adaptive_out_of_range_weight``,
  ``adaptive_anchor_fraction``, ``adaptive_anchors``, ``adaptive_anchor_seed``, ``adaptive_correction``,
  ``adaptive_correction_length``, ``adaptive_correction_tangent``, ``dem_particle_steps`` (trials + replays, what
  compares with FEM–DEM's ``dem_particle_steps``), ``dem_trial_particle_steps``,
  ``dem_replay_particle_steps``, ``dem_point_fraction`` (DEM points / points, mean over the steps)
  and ``dem_points_final``.

Zones the networks do not stand for: the networks learnt one material, so the points of a weak zone
(the biaxial test's trigger) are anchors, DEM from step 0 on: their own RVEs, of the weak packing.

Controls (``control``: ``linear_elastic`` or ``elastoplastic``, with ``schedule_from``): the same
run with the networks replaced by that analytic model (``config[control]``; the elastoplastic
model's defaults are fitted to the default-scale FEM–DEM Path1, ``materials/calibration.py``) and
the promotions copied from the network run whose DEM answers ``schedule_from`` holds
(:func:`dem_trajectories`, ``promoted_at``): the same DEM points at the same commits, so the same
DEM work; only what answers elsewhere differs. ``adaptive_indicator`` is then ``schedule``.

Checkpoint: that of every FEM run (``BoundaryValueProblem.run``), holding the set's state; the DEM
points resume by replay, bit for bit.

What the RVEs answered (``trajectories`` output, :func:`dem_trajectories`): one ``gp`` per point
that ran DEM (anchors and promoted points), its converged strain, DEM stress and tangent at every
commit from step 0 on (a promoted point's past commits from its replay). These are DEM data of the
points where the networks were unsure, a training source like an RVE-path set: the
active-learning round (``adaptive.active_learning``, ``workflow/rules/adaptive.smk``) trains on them.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np
import xarray as xr

from ..adaptive.material import AdaptiveMaterialPointSet, anchor_points
from ..data import read_run, write_run
from ..dem.subset import DemSubsetMaterialPointSet
from ..fem.problem import BoundaryValueProblem
from ..history import HIST, history_from_sequence
from ..materials import make_material
from ..tensors import COMP, TCOMP, tangent_to_upper
from .fem_dem import dem_newton_config
from .fem_ml import commits_of_steps, run_keeping_partial, spread_variables, surrogate_attributes, surrogate_material
from .problems import dem_packings, problem_and_path

# per-step values of the set's commit log that are not sums over the commits of a load step
LAST_OF_STEP = ("dem_points", "out_of_range_points", "out_of_range_excess", "off_training_points", "correction")
MAX_OF_STEP = ("dem_steps_max",)
#: what a file of :func:`dem_trajectories` holds (the ``trajectories`` output)
DEM_TRAJECTORY_VARIABLES = ("strain", "stress", "tangent", "history", "valid", "promoted_at")


def configured_anchors(config: dict, n_points: int) -> tuple[np.ndarray, int]:
    """The anchor points of a validated config's ``adaptive`` section and the seed that drew them
    (``adaptive.anchor_seed``, or the config's ``seed`` where that is null)."""
    section = config["adaptive"]
    seed = int(config["seed"] if section["anchor_seed"] is None else section["anchor_seed"])
    return anchor_points(n_points, float(section["anchor_fraction"]), seed), seed


def run_adaptive(config: dict, path_name: str, threshold: float, packing_paths: list[str],
                 sigma_model: str | Path, tangent_model: str | Path | None, tangent: str,
                 output: str | Path | None = None, checkpoint: str | Path | None = None,
                 n_workers: int | None = None, logger: logging.Logger | None = None,
                 allow_partial: bool = False, dask_client=None,
                 trajectories: str | Path | None = None, problem: str = "triaxial",
                 weak_packing: str | None = None, control: str | None = None,
                 schedule_from: str | Path | None = None) -> xr.Dataset:
    """One adaptive run of load path `path_name` at `threshold` (validated config); returns the run
    Dataset and writes it to `output` (if given), and what its RVEs answered to `trajectories` (if
    given; :func:`dem_trajectories`). A step that does not converge raises ConvergenceError, or with
    `allow_partial` keeps the converged steps (``completed = 0``). With `control`, the networks are
    replaced by that analytic model and the promotions copied from `schedule_from` (module docstring)."""
    logger = logger or logging.getLogger("granular_multiscale.drivers.adaptive")
    cfg = dem_newton_config(config, problem)
    bvp, load_path = problem_and_path(cfg, problem, path_name)
    packings, assignment = dem_packings(bvp, cfg, packing_paths, weak_packing)
    section = cfg["adaptive"]
    n = bvp.n_material_points
    workers = int(n_workers or cfg["dem"]["n_workers"])
    anchors, anchor_seed = configured_anchors(cfg, n)
    weak = np.flatnonzero(bvp.zones() != 0)
    if weak.size:
        logger.info("adaptive %s: the %d points of the weak zone are anchors (the run has the specimen's networks only)",
                    problem, weak.size)
        anchors = np.union1d(anchors, weak)
    t0 = time.perf_counter()
    if control is None:
        surrogate = surrogate_material(cfg, n, sigma_model, tangent_model, tangent, logger)
        schedule = None
    else:
        surrogate = make_material(control, n, cfg)
        schedule = promotion_schedule(schedule_from, n)
    if control is None and section["indicator"] == "spread" and surrogate.ensemble_size == 1 and 0 < threshold < np.inf:
        raise ValueError(f"config key 'adaptive.indicator': 'spread' needs an ensemble (surrogate.ensemble_size >= 2); "
                         f"the one network of {sigma_model} has no spread and would never promote a point")
    dem = DemSubsetMaterialPointSet.from_config(cfg, n, packings, n_workers=workers, logger=logger,
                                                dask_client=dask_client, assignment=assignment)
    material = AdaptiveMaterialPointSet(surrogate, dem, threshold, bvp.confining_pressure,
                                        section["indicator"], float(section["out_of_range_weight"]), anchors, logger,
                                        section["correction"], float(section["correction_length"]), schedule,
                                        bool(section["correction_tangent"]))
    startup = time.perf_counter() - t0
    answer = (f"NNσ {sigma_model} (ensemble of {surrogate.ensemble_size}, {tangent} tangent)" if control is None
              else f"control: the {control} model, promotions copied from {schedule_from}")
    logger.info(
        "adaptive FEM–DEM–ML %s %s: %d steps, %d material points, threshold %g on indicator %s, %d anchors; %s; "
        "RVEs of %d spheres on %d %s workers (ready in %.1f s); Newton tolerance %.1e",
        problem, path_name, load_path.n_steps, n, threshold, material.indicator, anchors.size, answer,
        int(dem.n_spheres.max()), workers, cfg["dem"]["executor"], startup, cfg["newton"]["tolerance"],
    )
    with material:
        ds = run_keeping_partial(bvp, material, load_path, checkpoint, logger, True, allow_partial,
                                 f"adaptive {problem} {path_name} at threshold {threshold:g}")
    if control is None:
        ds = ds.assign(spread_variables(surrogate, ds))
        ds.attrs.update(surrogate_attributes(surrogate, sigma_model, tangent_model))
    else:
        ds.attrs.update({"adaptive_control": control, "adaptive_schedule_from": str(schedule_from)})
    ds = ds.assign(adaptive_variables(material, ds))
    trial, replay = float(ds["particle_steps"].sum()), float(ds["replay_particle_steps"].sum())
    ds.attrs.update({
        "adaptive_threshold": float(threshold),
        "adaptive_indicator": material.indicator,
        "adaptive_out_of_range_weight": float(section["out_of_range_weight"]),
        "adaptive_anchor_fraction": float(section["anchor_fraction"]),
        "adaptive_anchors": anchors.size,
        "adaptive_anchor_seed": anchor_seed,
        "adaptive_correction": section["correction"],
        "adaptive_correction_length": float(section["correction_length"]),
        "adaptive_correction_tangent": int(section["correction_tangent"]),
        "dem_particle_steps": trial + replay,
        "dem_trial_particle_steps": trial,
        "dem_replay_particle_steps": replay,
        "dem_time_s": float(ds["dem_time"].sum() + ds["replay_dem_time"].sum()),
        "dem_point_fraction": float(ds["point_mode"].mean()),
        "dem_points_final": int(ds["dem_points"][-1]),
        "dem_startup_time_s": startup,
        "dem_n_spheres": int(dem.n_spheres.max()),
        "dem_n_workers": workers,
        "dem_executor": cfg["dem"]["executor"],
    })
    logger.info(
        "adaptive %s at threshold %g: %d of %d points in DEM at the end (%.1f %% of point-steps), %.3g DEM "
        "particle-steps (trials %.3g + replays %.3g), wall %.1f s", path_name, threshold, int(ds["dem_points"][-1]),
        n, 100 * ds.attrs["dem_point_fraction"], trial + replay, trial, replay, float(ds.attrs["time_run_s"]),
    )
    if trajectories is not None:
        dem_points = dem_trajectories(material, bvp, f"{path_name} at threshold {threshold:g}")
        write_run(dem_points, trajectories, config, required=DEM_TRAJECTORY_VARIABLES)
        logger.info("wrote %s: the DEM answers of %d points along their %d commits", trajectories,
                    dem_points.sizes["gp"], dem_points.sizes["step"] - 1)
    if output is not None:
        write_run(ds, output, config)
        logger.info("wrote %s", output)
    return ds


def promotion_schedule(trajectories: str | Path, n_points: int) -> np.ndarray:
    """[n_points] the commit at which each point of the run whose DEM answers `trajectories` holds
    turned DEM (``promoted_at``; −1: never), the promotions a control run copies."""
    if trajectories is None:
        raise ValueError("a control run copies the promotions of a network run: give its DEM answers (schedule_from)")
    points = read_run(trajectories, required=("promoted_at",))
    if int(points.attrs.get("n_points", -1)) != n_points:
        raise ValueError(f"{trajectories}: the DEM answers of a run with {points.attrs.get('n_points')} points, "
                         f"this run has {n_points}")
    schedule = np.full(n_points, -1)
    schedule[points["gp"].values.astype(int)] = points["promoted_at"].values.astype(int)
    return schedule


def dem_trajectories(material: AdaptiveMaterialPointSet, problem: BoundaryValueProblem, run: str) -> xr.Dataset:
    """The points of an adaptive run that ran DEM, as trajectories (one ``gp`` each, the mesh point's
    id): per commit ``strain``, ``stress``, ``tangent`` (upper triangle, as in the data contract),
    ``history`` and ``valid`` (the RVE's answer at that state is known: always, for these points),
    ``promoted_at`` (the point answered from DEM from this step on; 0 = anchor) and ``gp_position``.
    The step coordinate counts the solver's commits, from that of load step 0 (the consolidated
    state) on: without cut-backs it is the load step; a cut-back's sub-steps are states of their
    own, as in the networks' history variables."""
    responses = {k: v[1:] for k, v in material.dem.dem_responses().items()}  # [0]: before the first commit
    points = np.flatnonzero(material.dem_mode)
    strain = responses["strain"][:, points]
    known = responses["known"][:, points]
    stress = np.where(known[..., None], responses["stress"][:, points], np.nan)
    tangent = np.where(known[..., None], tangent_to_upper(responses["tangent"][:, points]), np.nan)
    uniform = material.n_points != problem.n_gauss_points  # the one point of a uniform field has no position
    positions = np.full((points.size, 3), np.nan) if uniform else problem.gp_positions[points]
    sgc = ("step", "gp", "comp")
    return xr.Dataset(
        {
            "strain": (sgc, strain, {"units": "1", "long_name": "converged strain of the point (tensorial shear)"}),
            "stress": (sgc, stress, {"units": "Pa", "long_name": "the point's RVE stress, tension positive"}),
            "tangent": (("step", "gp", "tcomp"), tangent, {"units": "Pa", "long_name": "upper triangle of the RVE's "
                                                                                       "tangent dσ/d(engineering ε)"}),
            "history": (("step", "gp", "hist"), history_from_sequence(strain), {"units": "1", "long_name": "φ1–φ3, ψ1, ψ2"}),
            "valid": (("step", "gp"), known, {"long_name": "the RVE's answer at this state is known"}),
            "promoted_at": (("gp",), material.promoted_at[points], {"long_name": "first step the point answered "
                                                                                 "from its RVE (0: anchor)"}),
            "gp_position": (("gp", "xyz"), positions, {"units": "m"}),
        },
        coords={"step": np.arange(strain.shape[0]), "gp": points, "comp": list(COMP), "tcomp": list(TCOMP),
                "hist": list(HIST), "xyz": ["x", "y", "z"]},
        attrs={
            "method": "adaptive_dem",
            "adaptive_run": run,
            "adaptive_threshold": material.threshold,
            "adaptive_indicator": material.indicator,
            "n_points": material.n_points,
            "n_dem_points": int(points.size),
            "confining_pressure_Pa": float(problem.confining_pressure),
            "step_meaning": "commit of the solver, from that of load step 0 (the consolidated state) on; "
                            "= the load step without cut-backs",
        },
    )


def adaptive_variables(material: AdaptiveMaterialPointSet, ds: xr.Dataset) -> dict[str, xr.Variable]:
    """Per load step of `ds`, from what the set recorded per commit: point_mode and indicator at the
    step's last commit, and the step_info values over all its commits (see the module docstring)."""
    ends = commits_of_steps(ds, material.commits)
    starts = np.concatenate([[0], ends[:-1]])
    mode = material.point_mode()[ends - 1]
    indicator = np.asarray(material.indicator_log)[ends - 1]
    n_gp = ds.sizes["gp"]
    if mode.shape[1] != n_gp:  # uniform field: the one material point stands for every Gauss point
        mode = np.broadcast_to(mode, (mode.shape[0], n_gp)).copy()
        indicator = np.broadcast_to(indicator, (indicator.shape[0], n_gp)).copy()
    out = {
        "point_mode": xr.Variable(("step", "gp"), mode.astype(np.int8), {
            "units": "1", "description": "1: the point answered from its YADE RVE at the converged state of the "
                                         "step, 0: from the surrogate (ensemble mean)"}),
        "indicator": xr.Variable(("step", "gp"), indicator, {
            "units": "1", "indicator": material.indicator, "threshold": material.threshold,
            "description": f"promotion indicator '{material.indicator}' of the surrogate at the converged strain; "
                           "a surrogate point is promoted to DEM when it reaches the threshold"}),
    }
    log = material.commit_log
    for key in log[0] if log else ():
        values = np.array([d.get(key, 0.0) for d in log], dtype=float)
        if key in LAST_OF_STEP:
            per_step = values[ends - 1]
        elif key in MAX_OF_STEP:
            per_step = np.array([values[a:b].max() for a, b in zip(starts, ends)])
        else:
            per_step = np.array([values[a:b].sum() for a, b in zip(starts, ends)])
        how = "at the end of" if key in LAST_OF_STEP else "largest over" if key in MAX_OF_STEP else "sum over"
        out[key] = xr.Variable(("step",), per_step, {"description": f"adaptive set '{key}', {how} the load step's "
                                                                    "commits (cut-back sub-steps included)"})
    return out
