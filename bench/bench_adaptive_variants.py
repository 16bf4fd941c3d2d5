"""Adaptive FEM–DEM–ML variants side by side, against the FEM–DEM reference of each load path.

Each variant is a set of `adaptive` settings (threshold, anchor share, correction) run with the
networks and RVE packings of a finished run of the pipeline; each row says what it cost (DEM
particle-steps of trials and replays, in % of the FEM–DEM run's; wall time) and how far it is from
FEM–DEM (top force: max over the path in % of the FEM–DEM peak; stress MAE over every Gauss point
and step), and how many Newton iterations a load step took on average (what a correction costs
Newton; `correction_tangent=false` leaves its slope out of the tangent). FEM–ML (the surrogate
alone) is the first row of every path. The rows are printed and written to the record (--out,
default {output_dir}/bench/adaptive_variants.json).

    .venv/bin/snakemake -j2 all --configfile config/config.yaml config/new_paths.yaml   # references of path3, path4
    .venv/bin/python bench/bench_adaptive_variants.py --paths path2 path3 path4 \
        --variant threshold=0.01 --variant anchor_fraction=0.1,correction=kernel,threshold=inf \
        --configfile config/config.yaml config/new_paths.yaml

The problems beyond the triaxial specimen (--problems biaxial footing: each one's first load path,
against its FEM–DEM run of the pipeline) get the columns of their surrogate tables instead
(``analysis/problem_surrogate.py``: force up to and after the peak, volumetric strain, band,
stress MAE inside and outside the band or under the footing, DEM share, DEM points at the end and
their share in the band, wall time). With --controls each variant of a problem is followed by its
controls (adaptive.controls): the same DEM points, promoted at the same steps, with the networks
replaced by the analytic model.

    .venv/bin/python bench/bench_adaptive_variants.py --paths --problems footing --controls \
        --variant indicator=off_training,threshold=0.5 --variant threshold=0.02

--models runs every variant with another training's networks (the folder bench/bench_trainings.py
writes), against the same references; their runs are kept apart from the pipeline networks'.

A variant is `key=value` pairs of the config section `adaptive` (threshold: one of its thresholds;
.inf / inf for none; tangent: the networks' tangent); what it leaves out comes from the config.
Runs are written to adaptive_variants_runs/<variant>/<path>.h5 (problems:
<variant>/<problem>/<case>.h5, controls <variant>,control=<model>/...) beside the record and reused
when they exist (delete to rerun).
"""

from __future__ import annotations

import copy
import logging
import re
import time
from pathlib import Path

import numpy as np
import pandas as pd

from granular_multiscale.analysis.problem_surrogate import comparison_table
from granular_multiscale.config import adaptive_tangent, validate_config
from granular_multiscale.data import read_run, write_run
from granular_multiscale.drivers.adaptive import run_adaptive
from granular_multiscale.drivers.fem_ml import run_fem_ml
from granular_multiscale.plan import WEAK_ZONE_ROUND, Plan

from common import bench_parser, parse_variant, pipeline_models, require_files, run_folder, top_force_error_pct, variant_name


def measure(reference, run, wall: float) -> dict:
    steps = min(reference.sizes["step"], run.sizes["step"])
    stress_error = np.abs(run["stress"].values[:steps] - reference["stress"].values[:steps])
    dem = float(run.attrs.get("dem_particle_steps", 0.0))
    replay = float(run.attrs.get("dem_replay_particle_steps", 0.0))
    total = float(reference.attrs["dem_particle_steps"])
    return {
        "steps": f"{steps - 1}/{reference.sizes['step'] - 1}",
        "top_force_pct_of_peak": top_force_error_pct(reference, run),
        "stress_mae_kpa": float(stress_error.mean() / 1e3),
        "dem_share_pct": 100 * dem / total,
        "replay_share_pct": 100 * replay / total,
        "dem_points_final": int(run.attrs.get("dem_points_final", 0)),
        # a correction couples the points (and without correction_tangent its own slope is not in the tangent)
        "newton_iterations_per_step": float(run["newton_iterations"].values[1:steps].mean()),
        "wall_s": wall,
    }


def variant_config(config: dict, text: str) -> tuple[dict, float, str]:
    """The validated config of a variant 'key=value,...' of the section adaptive, its threshold and
    its name (the folder of its runs)."""
    variant = parse_variant(text)
    threshold = float(variant.pop("threshold"))
    cfg = copy.deepcopy(config)
    cfg["adaptive"].update(variant)
    return validate_config(cfg), threshold, variant_name({**variant, "threshold": threshold})


def models_folder_name(models: Path) -> str:
    """The folder, beside the pipeline networks' runs, of the runs made with other networks."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", f"models={Path(models).resolve()}")


def problem_rows(plan: Plan, problem: str, variants: list[str], controls: bool, folder: Path, workers: int,
                 models: Path | None = None) -> list[dict]:
    """FEM–ML and every variant (and its controls) on the first load path of `problem`, against
    the pipeline's FEM–DEM run of it: rows of its surrogate table. `models`: a folder with other
    networks of the same names (another training), whose FEM–ML run is made under `folder`."""
    config, L = plan.config, plan.layout
    case = plan.problem_cases[problem][0]
    sigma, tangent_model = pipeline_models(config, models)
    if models is not None:  # other networks' runs apart from the pipeline's
        folder = folder / models_folder_name(models)
    weak = plan.weak_zone_models(problem)
    if models is not None:
        weak = {key: Path(models) / f"{WEAK_ZONE_ROUND}{Path(file).name}" for key, file in weak.items()}  # as bench_trainings
    tangent = config["surrogate"]["tangent"]
    weak_packing = next(iter(plan.weak_packing_input(problem)), None)
    reference_file = plan.problem_run(problem, case)
    require_files(reference_file, sigma, tangent_model, *weak.values(),
                  hint="run the pipeline with the problem (`snakemake -j2 all`) first")
    file = Path(L.problem_run(problem, "fem_ml", case)) if models is None else folder / "fem_ml" / problem / f"{case}.h5"
    if not file.is_file():
        file.parent.mkdir(parents=True, exist_ok=True)
        write_run(run_fem_ml(config, case, sigma, tangent_model, tangent, progress=False, allow_partial=True,
                             problem=problem, weak_zone_models={k.removeprefix("weak_"): v for k, v in weak.items()}
                             or None), file, config)
    runs = {"FEM–ML": read_run(file)}
    for text in variants:
        cfg, threshold, name = variant_config(config, text)
        schedule = None
        for control in [None, *(plan.controls if controls else [])]:
            label = name if control is None else f"{name},control={control}"
            out = folder / label / problem / f"{case}.h5"
            trajectories = out.with_name(f"{case}_dem_points.h5")
            if not out.is_file():
                out.parent.mkdir(parents=True, exist_ok=True)
                t0 = time.perf_counter()
                # a control has no network inputs to carry a residual in: its correction is none
                run_cfg = cfg if control is None else {**cfg, "adaptive": {**cfg["adaptive"], "correction": "none"}}
                run_adaptive(run_cfg, case, threshold, plan.packings, sigma, tangent_model, adaptive_tangent(cfg),
                             output=out,
                             checkpoint=out.with_suffix(".ckpt"), n_workers=workers, allow_partial=True,
                             trajectories=trajectories, problem=problem, weak_packing=weak_packing,
                             control=control, schedule_from=schedule)
                print(f"{problem} {label}: {time.perf_counter() - t0:.0f} s", flush=True)
            runs[label] = read_run(out)
            schedule = schedule or trajectories  # the controls copy the network run's promotions
    table = comparison_table(read_run(reference_file), runs)
    return [{"problem": problem, **row} for row in table.to_dict("records")]


def main(argv=None) -> list[dict]:
    parser = bench_parser("adaptive_variants", __doc__)
    parser.add_argument("--paths", nargs="*", default=["path2"])
    parser.add_argument("--problems", nargs="*", default=[], choices=["biaxial", "footing"])
    parser.add_argument("--controls", action="store_true",
                        help="each variant of a problem followed by its controls (adaptive.controls)")
    parser.add_argument("--models", type=Path, default=None,
                        help="a folder with other networks of the pipeline's names (another training; "
                             "bench/bench_trainings.py writes them), instead of the pipeline's")
    parser.add_argument("--variant", action="append", default=[], help="adaptive settings, key=value,...")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)

    config = args.config
    plan = Plan(config)
    sigma, tangent_model = pipeline_models(config, args.models)
    packings = plan.packings
    tangent = config["surrogate"]["tangent"]
    references = {path: plan.layout.run("fem_dem", path) for path in args.paths}
    require_files(sigma, tangent_model, *packings, *references.values(),
                  hint="run the pipeline (docstring of bench/bench_adaptive_variants.py) first")
    measurement = parser.measurement(args)
    path_runs = run_folder(args) if args.models is None else run_folder(args) / models_folder_name(args.models)
    rows = []
    for path in args.paths:
        reference = read_run(references[path])
        file = Path(plan.layout.fem_ml(path))  # the pipeline's, or the same run made here
        fem_ml = (read_run(file) if file.is_file() and args.models is None
                  else run_fem_ml(config, path, sigma, tangent_model, tangent, progress=False))
        rows.append({"path": path, "variant": "FEM–ML", **measure(reference, fem_ml, float(fem_ml.attrs["time_run_s"]))})
        print(rows[-1], flush=True)
        for text in args.variant:
            cfg, threshold, name = variant_config(config, text)
            file = path_runs / name / f"{path}.h5"
            if file.is_file():
                run = read_run(file)
                wall = float(run.attrs["time_run_s"])
            else:
                t0 = time.perf_counter()
                run = run_adaptive(cfg, path, threshold, packings, sigma, tangent_model, adaptive_tangent(cfg),
                                   output=file,
                                   checkpoint=file.with_suffix(".ckpt"), n_workers=args.workers)
                wall = time.perf_counter() - t0
            rows.append({"path": path, "variant": name, **measure(reference, run, wall)})
            print(rows[-1], flush=True)
    if rows:
        table = pd.DataFrame(rows)
        with pd.option_context("display.width", 200, "display.max_columns", 20):
            print(table.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    for problem in args.problems:
        problem_table = problem_rows(plan, problem, args.variant, args.controls, run_folder(args), args.workers,
                                     args.models)
        rows += problem_table
        with pd.option_context("display.width", 250, "display.max_columns", 40, "display.max_colwidth", 14):
            print(pd.DataFrame(problem_table).set_index("run").T.to_string(float_format=lambda v: f"{v:.3g}"), flush=True)
        measurement.finish(rows, args.out)  # after every problem: a stopped bench keeps what it measured
    measurement.finish(rows, args.out)
    print(f"wrote {args.out}")
    return rows


if __name__ == "__main__":
    main()
