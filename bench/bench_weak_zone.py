"""The biaxial test's weak zone: its networks trained on more RVE-path data, over several seeds.

FEM–ML's band forms where the weak zone's networks put it, so their error moves the force up to the
peak. For the weak zone's training sources of the config (``surrogate.weak_zone_sources``), for
the same plus each ``--extra-sets`` (RVE-path sets of the weak packing), and for each training
seed (the config's seed plus each ``--seeds`` offset):

* the weak zone's NNσ trained on them (its ND is the pipeline's, unused with the autodiff tangent)
  and its held-out MAE of σ33 on that training's own split;
* the networks driven along the FEM–DEM strain histories of the weak zone's points (no FEM: the
  material error alone), ‖σ − σ_ref‖ / p0, median over the points and the steps up to the
  reference's peak and after it; the specimen's networks at the other points beside them;
* FEM–ML on the biaxial test with them against FEM–DEM (the columns of the problems' surrogate
  tables). The specimen's networks are the pipeline's throughout.

    .venv/bin/snakemake -j2 all
    .venv/bin/snakemake -j2 --configfile config/config.yaml config/weak_zone_more.yaml -- \
        results/rve_paths/band_weak_more.h5 results/rve_paths/band_weak_other.h5
    .venv/bin/python bench/bench_weak_zone.py --seeds 0 1 2 --extra-sets band_weak_more \
        --extra-sets band_weak_other

Each training and its FEM–ML run are kept under weak_zone_runs/ beside the record and reused when they
exist (delete to rerun)."""

from __future__ import annotations

import logging

import numpy as np
import pandas as pd

from granular_multiscale.analysis.problem_surrogate import comparison_table
from granular_multiscale.data import read_run, write_run
from granular_multiscale.drivers.fem_ml import run_fem_ml
from granular_multiscale.fem import make_problem
from granular_multiscale.plan import WEAK_ZONE_ROUND, Plan
from granular_multiscale.surrogate.dataset import build_dataset_from_sources
from granular_multiscale.surrogate.training import train

from common import bench_parser, driven_response, require_files, run_folder


def main(argv=None) -> list[dict]:
    parser = bench_parser("weak_zone", __doc__)
    parser.add_argument("--extra-sets", nargs="+", action="append", default=[], metavar="SET",
                        help="RVE-path sets of the weak packing added to the weak zone's sources: one more variant "
                             "each time the option is given")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0], help="training seeds: offsets to the config's seed")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    logger = logging.getLogger("bench.weak_zone")

    plan = Plan(args.config)
    L, config = plan.layout, args.config
    if "biaxial" not in plan.problems or not plan.weak_zone_sets:
        raise SystemExit("config keys 'problems' and 'surrogate.weak_zone_sources': the bench needs the biaxial "
                         "test and the weak zone's networks")
    case = plan.problem_cases["biaxial"][0]
    reference_file = plan.problem_run("biaxial", case)
    variants = [list(plan.weak_zone_sets)] + [[*plan.weak_zone_sets, *extra] for extra in args.extra_sets]
    require_files(reference_file, L.model("sigma"), L.model("tangent"), L.model("tangent", WEAK_ZONE_ROUND),
                  *(L.rve_paths(name) for sets in variants for name in sets),
                  hint="run the pipeline (`snakemake -j2 all`) and make the extra sets first (see the docstring)")
    reference = read_run(reference_file)
    weak = make_problem(config, "biaxial").zones() == 1
    strain = reference["strain"].transpose("step", "gp", ...).values
    stress = reference["stress"].transpose("step", "gp", ...).values
    peak_step = int(np.argmax(np.abs(reference["load_force"].values)))
    p0 = float(config["specimen"]["confining_pressure"])

    def driven_error(model_file, points: np.ndarray) -> np.ndarray:
        """[steps, points] ‖σ − σ_ref‖ / p0 of the networks along those points' FEM–DEM histories."""
        return np.linalg.norm(driven_response(model_file, strain[:, points], p0)[0] - stress[:, points], axis=-1) / p0

    # the specimen's networks along the other points' histories: what the weak zone's are measured against
    specimen = driven_error(L.model("sigma"), ~weak)
    specimen_driven = {"up to the peak (p0)": float(np.median(specimen[:peak_step + 1])),
                       "after the peak (p0)": float(np.median(specimen[peak_step + 1:]))}
    print("the specimen's networks driven along their points' FEM–DEM histories:", specimen_driven, flush=True)
    surrogate = config["surrogate"]

    measurement = parser.measurement(args)
    rows = []
    for sets in variants:
        sources = [(name, read_run(L.rve_paths(name), required=("strain", "stress", "tangent"))) for name in sets]
        train_set, heldout = build_dataset_from_sources(  # one split of the sources for every seed, as the rule's
            sources, surrogate["train_fraction"], config["seed"], split=surrogate["split"],
            history_tolerance=surrogate["history_tolerance"])
        for offset in args.seeds:
            folder = run_folder(args) / "+".join(sets) / f"seed{offset}"
            folder.mkdir(parents=True, exist_ok=True)
            sigma_file, run_file = folder / "nn_sigma.pt", folder / f"biaxial_{case}.h5"
            if not sigma_file.is_file():
                model, _, mae = train(train_set, heldout, "sigma", plan.training_settings(), int(config["seed"]) + offset,
                                      use_history=True, config=config, logger=logger)
                model.save(sigma_file)
                mae.to_csv(folder / "sigma_mae.csv", index=False)
            mae = pd.read_csv(folder / "sigma_mae.csv").set_index("target")
            if not run_file.is_file():
                write_run(run_fem_ml(config, case, L.model("sigma"), L.model("tangent"), surrogate["tangent"],
                                     logger=logger, progress=False, allow_partial=True, problem="biaxial",
                                     weak_zone_models={"sigma": sigma_file,
                                                       "tangent": L.model("tangent", WEAK_ZONE_ROUND)}),
                          run_file, config)
            driven = driven_error(sigma_file, weak)
            table = comparison_table(reference, {"FEM–ML": read_run(run_file)}).iloc[0].drop("run").to_dict()
            rows.append({"sources": " + ".join(sets), "training seed": int(config["seed"]) + offset,
                         "trajectories": sum(run.sizes["gp"] for _, run in sources),
                         "held-out σ33 MAE (kPa)": float(mae.loc["stress_33", "heldout_mae_pa"]) / 1e3,
                         "train σ33 MAE (kPa)": float(mae.loc["stress_33", "train_mae_pa"]) / 1e3,
                         "driven weak zone, up to the peak (p0)": float(np.median(driven[:peak_step + 1])),
                         "driven weak zone, after the peak (p0)": float(np.median(driven[peak_step + 1:])),
                         **table})
            print(rows[-1], flush=True)
    columns = ["sources", "training seed", "held-out σ33 MAE (kPa)", "driven weak zone, up to the peak (p0)",
               "force: up to the peak (%)", "force: after the peak (%)",
               "volumetric strain: largest error (% of its peak)", "inclination − reference (deg)",
               "onset − reference (% strain)"]
    with pd.option_context("display.width", 250, "display.max_columns", 20):
        print(pd.DataFrame(rows)[columns].to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    measurement.finish({"specimen driven": specimen_driven, "rows": rows}, args.out)
    print(f"wrote {args.out}")
    return rows


if __name__ == "__main__":
    main()
