"""The default networks against independent trainings of them: the same datasets, other seeds.

One training's seed moves its errors; a result is the surrogate's only if it holds across
trainings. For the pipeline's networks (training 0, seed `seed`) and each further seed, the
validation path's FEM–ML run, each problem's FEM–ML run and the biaxial test's adaptive run at
its section's `adaptive` settings (the weak zone in DEM) against their FEM–DEM references: force
(largest error, up to the reference's peak and after it) and volumetric strain in % of their
peaks, band inclination and onset against the reference's, stress MAE inside and outside the band
(under the footing and elsewhere), DEM share and wall time — the columns of the problems'
surrogate tables (``analysis/problem_surrogate.py``), and beside the ensemble spread's rank
correlation with the error after the peak that of the distance to the training states (does
either say *where* the networks are wrong?). For the FEM–ML runs also the spread's calibration:
median error / spread, as measured and scaled by the scale of the run's own networks on their
held-out trajectories (``analysis/calibration.py``). Rows "driven <problem>": the same networks
driven along the reference's strain histories, no FEM (``drivers.fem_ml.run_along_reference``, rule
problem_fem_ml_driven): their error is the material's alone, FEM–ML's also the field's. Rows
"as reference <problem>": FEM–ML solved with the reference's Newton settings and ND's tangent
(rule problem_fem_ml_as_reference).

    .venv/bin/snakemake -j2 all                       # the pipeline: datasets, networks, references
    .venv/bin/python bench/bench_trainings.py --seeds 1

Each further training writes NNσ and ND (and the weak zone's, with surrogate.weak_zone_sources)
under trainings_runs/seed<k>/ beside the record, and its runs there; both are reused when they
exist (delete to rerun). Training 0's runs are the pipeline's files.
"""

from __future__ import annotations

import functools
import logging
import time
from pathlib import Path

import numpy as np
import pandas as pd

from granular_multiscale.analysis import calibration
from granular_multiscale.analysis.problem_surrogate import (comparison_table, first_step_after_peak,
                                                            rank_correlation_after_peak, run_features, stress_errors)
from granular_multiscale.config import adaptive_tangent, problem_adaptive_config
from granular_multiscale.data import read_run, write_run
from granular_multiscale.drivers.adaptive import run_adaptive
from granular_multiscale.drivers.fem_ml import run_along_reference, run_fem_ml
from granular_multiscale.fem import make_problem
from granular_multiscale.novelty import TrainingStates
from granular_multiscale.plan import WEAK_ZONE_ROUND, Plan
from granular_multiscale.surrogate.dataset import read_dataset
from granular_multiscale.surrogate.models import SurrogateModel
from granular_multiscale.surrogate.training import heldout_spread_scale, train

from common import bench_parser, curve_error_pct, require_files, run_folder

ROUNDS = {"": "the specimen's", WEAK_ZONE_ROUND: "the weak zone's"}
#: a training's runs of each problem: {row name: run folder}
PROBLEM_RUNS = {"FEM–ML": "fem_ml", "as reference": "fem_ml_as_reference", "driven": "fem_ml_driven"}


def train_networks(plan: Plan, seed: int, folder: Path, logger) -> dict[str, dict[str, Path]]:
    """{round: {sigma, tangent: model file}} trained with `seed` on the pipeline's datasets (reused
    when the files exist)."""
    config, L = plan.config, plan.layout
    rounds = {""} | ({WEAK_ZONE_ROUND} if plan.weak_zone_sets else set())
    models = {}
    for round_ in sorted(rounds):
        models[round_] = {}
        for kind in ("sigma", "tangent"):
            file = folder / f"{round_}nn_{kind}.pt"
            if not file.is_file():
                data = read_dataset(L.dataset("train", round_)), read_dataset(L.dataset("heldout", round_))
                t0 = time.perf_counter()
                model, _, _ = train(*data, kind, plan.training_settings(), seed, use_history=True, config=config,
                                    logger=logger)
                file.parent.mkdir(parents=True, exist_ok=True)
                model.save(file)
                print(f"trained {ROUNDS[round_]} {kind} network, seed {seed}: {time.perf_counter() - t0:.0f} s",
                      flush=True)
            models[round_][kind] = file
    return models


def runs_of(plan: Plan, models: dict | None, folder: Path, workers: int, logger) -> list[tuple[str, str, Path]]:
    """[(what, problem, run file)] of one training (problem "triaxial": the validation path): the
    pipeline's files for training 0 (`models` None), else runs made here with `models` under
    `folder` (reused when they exist). Each problem's first load path, FEM–ML also driven along its
    reference's strains."""
    config, L = plan.config, plan.layout
    tangent = config["surrogate"]["tangent"]
    path = plan.validation_path
    cases = {problem: plan.problem_cases[problem][0] for problem in plan.problems}
    adaptive = "biaxial" in cases and plan.problem_adaptive
    if models is None:
        runs = [(f"FEM–ML {path}", "triaxial", Path(L.fem_ml(path)))]
        for problem, case in cases.items():
            runs += [(f"{what} {problem}", problem, Path(L.problem_run(problem, folder_name, case)))
                     for what, folder_name in PROBLEM_RUNS.items()]
        if adaptive:
            runs.append(("adaptive biaxial", "biaxial",
                         Path(L.problem_run("biaxial", plan.problem_adaptive_method, cases["biaxial"]))))
        return runs
    specimen, weak = models[""], models.get(WEAK_ZONE_ROUND)
    runs = []

    def made(what: str, problem: str, file: Path, make) -> None:
        if not file.is_file():
            file.parent.mkdir(parents=True, exist_ok=True)
            t0 = time.perf_counter()
            make(file)
            print(f"{what}: {time.perf_counter() - t0:.0f} s", flush=True)
        runs.append((what, problem, file))

    def fem_ml(problem: str, case: str, weak_models, tangent=tangent, solver="fem_ml"):
        return lambda file: write_run(run_fem_ml(
            config, case, specimen["sigma"], specimen["tangent"], tangent, logger=logger, progress=False,
            allow_partial=True, problem=problem, weak_zone_models=weak_models, solver=solver), file, config)

    def driven(problem: str, case: str, weak_models):
        return lambda file: write_run(run_along_reference(
            config, read_run(plan.problem_run(problem, case)), specimen["sigma"], specimen["tangent"], tangent, problem,
            weak_zone_models=weak_models, logger=logger), file, config)

    made(f"FEM–ML {path}", "triaxial", folder / "fem_ml" / f"{path}.h5", fem_ml("triaxial", path, None))
    for problem, case in cases.items():
        weak_models = weak if problem == "biaxial" else None
        make = {"fem_ml": fem_ml(problem, case, weak_models),
                "fem_ml_as_reference": fem_ml(problem, case, weak_models, "nn", "reference"),
                "fem_ml_driven": driven(problem, case, weak_models)}
        for what, folder_name in PROBLEM_RUNS.items():
            made(f"{what} {problem}", problem, folder / problem / folder_name / f"{case}.h5", make[folder_name])
    if adaptive:
        case = cases["biaxial"]
        biaxial_config, threshold = problem_adaptive_config(config, "biaxial")
        made("adaptive biaxial", "biaxial", folder / "biaxial" / plan.problem_adaptive_method / f"{case}.h5",
             lambda file: run_adaptive(
                 biaxial_config, case, threshold, plan.packings, specimen["sigma"], specimen["tangent"],
                 adaptive_tangent(biaxial_config),
                 output=file, checkpoint=file.with_suffix(".ckpt"), n_workers=workers, logger=logger,
                 allow_partial=True, problem="biaxial", weak_packing=plan.weak_packing_input("biaxial")[0]))
    return runs


def networks_by_zone(run, zones) -> list[tuple[str, np.ndarray]]:
    """[(NNσ model file, [n_gp] its points)] of a FEM–ML run: the specimen's networks, and the weak
    zone's at zone 1 when the run names them."""
    weak = run.attrs.get("surrogate_weak_zone_sigma_model")
    if not weak:
        return [(run.attrs["surrogate_sigma_model"], np.ones(run.sizes["gp"], dtype=bool))]
    return [(file, zones == zone) for zone, file in enumerate([run.attrs["surrogate_sigma_model"], weak])
            if (zones == zone).any()]


def training_distance(run, zones) -> np.ndarray:
    """[steps, n_gp] each point's distance to its networks' training states (the k-th nearest, over
    the radius that 99 % of the training states are within), along the run's converged strains: the
    indicator of "off the training data", for the weak zone's points (zone 1) from its own networks."""
    distance = np.zeros((run.sizes["step"], run.sizes["gp"]))
    for file, points in networks_by_zone(run, zones):
        model = SurrogateModel.load(file)
        states = TrainingStates(model.training_states, radius=model.training_radius)
        distance[:, points] = states.distance(run_features(run, model.history)[:, points]) / states.radius
    return distance


@functools.lru_cache(maxsize=None)
def spread_scale(model_file: str, heldout_file: str) -> float:
    """The scale of a model file's spread on a held-out dataset (each training's runs share them)."""
    return heldout_spread_scale(SurrogateModel.load(model_file), read_dataset(heldout_file))["scale"]


def scaled_calibration(plan: Plan, run, reference) -> dict:
    """A FEM–ML run's median error / spread over every (step ≥ 1, point), as measured and with each
    point's spread scaled by its networks' scale on their held-out trajectories (the run's own model
    files, the pipeline's held-out datasets: every training shares them)."""
    files = {"specimen": (run.attrs["surrogate_sigma_model"], plan.layout.dataset("heldout"))}
    if run.attrs.get("surrogate_weak_zone_sigma_model"):
        files["weak_zone"] = (run.attrs["surrogate_weak_zone_sigma_model"], plan.layout.dataset("heldout", WEAK_ZONE_ROUND))
    scales = {name: spread_scale(str(model), str(heldout)) for name, (model, heldout) in files.items()}
    points = calibration.calibration_points(run, reference, spread_scale=calibration.point_spread_scales(run, scales))
    everything = calibration.calibration_table(points).iloc[-1]
    return {"spread scale": scales["specimen"], "median error / spread": everything.median_error_over_spread,
            "median error / (scale × spread)": everything.median_error_over_scaled_spread}


def compare(plan: Plan, problem: str, file: Path) -> dict:
    """The errors of one run against its FEM–DEM reference."""
    run = read_run(file)
    fem_ml = "point_mode" not in run  # not an adaptive run
    if problem == "triaxial":
        reference = read_run(plan.reference_run(plan.validation_path))
        return {"force: largest error (% of peak)": curve_error_pct(reference, run, "top_force")["all"],
                "volumetric strain: largest error (% of its peak)":
                    curve_error_pct(reference, run, "volumetric_strain")["all"],
                "wall time (s)": float(run.attrs["time_run_s"]), **scaled_calibration(plan, run, reference)}
    reference = read_run(plan.problem_run(problem, plan.problem_cases[problem][0]))
    row = comparison_table(reference, {"run": run}).iloc[0].drop("run").to_dict()
    zones = make_problem(plan.config, problem).zones()
    after = slice(first_step_after_peak(reference), None)
    row["median stress error after the peak (p0)"] = float(np.median(stress_errors(reference, run)[after])) / float(
        reference.attrs["confining_pressure_Pa"])
    if fem_ml:
        row.update(scaled_calibration(plan, run, reference))
    row["distance–error rank correlation (after the peak)"] = rank_correlation_after_peak(
        reference, run, training_distance(run, zones))
    return row


def main(argv=None) -> list[dict]:
    parser = bench_parser("trainings", __doc__)
    parser.add_argument("--seeds", nargs="*", type=int, default=[1],
                        help="further trainings: the config's seed plus each of these (none: the pipeline's networks only)")
    parser.add_argument("--workers", type=int, default=2, help="RVE worker processes of the adaptive run")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    logger = logging.getLogger("bench.trainings")

    plan = Plan(args.config)
    L = plan.layout
    rounds = [""] + ([WEAK_ZONE_ROUND] if plan.weak_zone_sets else [])
    require_files(*(L.dataset(split, r) for r in rounds for split in ("train", "heldout")),
                  *(L.model(kind, r) for r in rounds for kind in ("sigma", "tangent")),
                  *plan.packings, plan.reference_run(plan.validation_path),
                  *(plan.problem_run(p, plan.problem_cases[p][0]) for p in plan.problems),
                  hint="run the pipeline (`snakemake -j2 all`) first")
    measurement = parser.measurement(args)
    rows = []
    for offset in [0, *args.seeds]:
        seed = int(args.config["seed"]) + offset
        folder = run_folder(args) / f"seed{seed}"
        models = None if offset == 0 else train_networks(plan, seed, folder / "models", logger)
        for what, problem, file in runs_of(plan, models, folder, args.workers, logger):
            rows.append({"training seed": seed, "what": what, **compare(plan, problem, file)})
            print(rows[-1], flush=True)
    table = pd.DataFrame(rows).set_index(["what", "training seed"]).sort_index().T  # a column per run
    with pd.option_context("display.width", 250, "display.max_columns", 30, "display.max_colwidth", 12):
        print(table.to_string(float_format=lambda v: f"{v:.3g}"))
    measurement.finish({"rows": rows}, args.out)
    print(f"wrote {args.out}")
    return rows


if __name__ == "__main__":
    main()
