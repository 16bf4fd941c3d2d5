"""Adaptive FEM–DEM–ML variants side by side, against the FEM–DEM reference of each load path.

Each variant is a set of `adaptive` settings (threshold, anchor share, correction) run with the
networks and RVE packing of a finished run of the pipeline; each row says what it cost (DEM
particle-steps of trials and replays, in % of the FEM–DEM run's; wall time) and how far it is from
FEM–DEM (top force: max over the path in % of the FEM–DEM peak; stress MAE over every Gauss point
and step). FEM–ML (the surrogate alone) is the first row of every path.

    .venv/bin/snakemake -j2 all --configfile config/config.yaml config/new_paths.yaml   # references of path3, path4
    .venv/bin/python bench/bench_adaptive_variants.py --paths path2 path3 path4 \
        --variant threshold=0.01 --variant anchor_fraction=0.1,correction=kernel,threshold=inf \
        --configfile config/config.yaml config/new_paths.yaml --csv results/adaptive_variants.csv

A variant is `key=value` pairs of the config section `adaptive` (threshold: one of its thresholds;
.inf / inf for none); what it leaves out comes from the config. Runs are written to
{output_dir}/adaptive_variants/<variant>/<path>.h5 and reused when they exist (delete to rerun).
"""

from __future__ import annotations

import argparse
import copy
import logging
import time
from pathlib import Path

import numpy as np
import pandas as pd
import yaml
from snakemake.utils import update_config

from granular_multiscale.analysis.metrics import curve_errors
from granular_multiscale.config import validate_config
from granular_multiscale.data import read_run
from granular_multiscale.drivers.adaptive import run_adaptive
from granular_multiscale.drivers.fem_ml import run_fem_ml

from common import parse_variant, variant_name


def measure(reference, run, wall: float) -> dict:
    top = curve_errors(reference, run).query("quantity == 'top_force' and phase == 'all'")
    steps = min(reference.sizes["step"], run.sizes["step"])
    stress_error = np.abs(run["stress"].values[:steps] - reference["stress"].values[:steps])
    dem = float(run.attrs.get("dem_particle_steps", 0.0))
    replay = float(run.attrs.get("dem_replay_particle_steps", 0.0))
    total = float(reference.attrs["dem_particle_steps"])
    return {
        "steps": f"{steps - 1}/{reference.sizes['step'] - 1}",
        "top_force_pct_of_peak": float(top["max_error_percent_of_peak"].iloc[0]),
        "stress_mae_kpa": float(stress_error.mean() / 1e3),
        "dem_share_pct": 100 * dem / total,
        "replay_share_pct": 100 * replay / total,
        "dem_points_final": int(run.attrs.get("dem_points_final", 0)),
        "wall_s": wall,
    }


def main() -> pd.DataFrame:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--configfile", nargs="+", default=["config/config.yaml"],
                        help="config files merged in order (as Snakemake's --configfile)")
    parser.add_argument("--paths", nargs="+", default=["path2"])
    parser.add_argument("--variant", action="append", default=[], help="adaptive settings, key=value,...")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--csv", default=None)
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)

    config = {}
    for name in args.configfile:
        update_config(config, yaml.safe_load(Path(name).read_text()))
    config = validate_config(config)
    out = Path(config["output_dir"])
    sigma, tangent_model = out / "models" / "nn_sigma.pt", out / "models" / "nn_tangent.pt"
    packings = sorted(str(p) for p in (out / "rve").glob("packing_*.yade.gz"))
    tangent = config["surrogate"]["tangent"]
    for f in (sigma, tangent_model, *[out / "fem_dem" / f"{p}.h5" for p in args.paths]):
        if not Path(f).is_file():
            raise SystemExit(f"bench_adaptive_variants: {f} not found: run the pipeline (module docstring) first")
    rows = []
    for path in args.paths:
        reference = read_run(out / "fem_dem" / f"{path}.h5")
        file = out / "fem_ml" / f"{path}.h5"  # the pipeline's, or the same run made here
        fem_ml = read_run(file) if file.is_file() else run_fem_ml(config, path, sigma, tangent_model, tangent,
                                                                  progress=False)
        rows.append({"path": path, "variant": "FEM–ML", **measure(reference, fem_ml, float(fem_ml.attrs["time_run_s"]))})
        print(rows[-1], flush=True)
        for text in args.variant:
            variant = parse_variant(text)
            threshold = float(variant.pop("threshold"))
            cfg = copy.deepcopy(config)
            cfg["adaptive"].update(variant)
            cfg = validate_config(cfg)
            name = variant_name({**variant, "threshold": threshold})
            file = out / "adaptive_variants" / name / f"{path}.h5"
            if file.is_file():
                run = read_run(file)
                wall = float(run.attrs["time_run_s"])
            else:
                t0 = time.perf_counter()
                run = run_adaptive(cfg, path, threshold, packings, sigma, tangent_model, tangent, output=file,
                                   checkpoint=file.with_suffix(".ckpt"), n_workers=args.workers)
                wall = time.perf_counter() - t0
            rows.append({"path": path, "variant": name, **measure(reference, run, wall)})
            print(rows[-1], flush=True)
    table = pd.DataFrame(rows)
    with pd.option_context("display.width", 200, "display.max_columns", 20):
        print(table.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    if args.csv:
        table.to_csv(args.csv, index=False)
    return table


if __name__ == "__main__":
    main()
