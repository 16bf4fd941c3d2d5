"""The biaxial FEM–DEM reference's own error: the same run at the default Newton tolerance of the
plane-strain problems (biaxial.dem_newton.tolerance: 0.02 at the default scale, 0.05 at the tiny
one) and at tighter ones, side by side.

    .venv/bin/python bench/bench_biaxial_tolerance.py                    # tiny: 2 x 4 mesh, 100 spheres
    .venv/bin/python bench/bench_biaxial_tolerance.py --tolerances 0.02 0.01 --segments '[[9, 0.045]]' \
        --out results/bench/biaxial_tolerance_prepeak.json

Each run uses the configured biaxial section (--configfile, default config/tiny.yaml: 2 x 4 quad8,
a frictionless weak zone, to 7 %, as the YADE band test of tests/test_problems.py) with RVEs of
--spheres spheres; the runs and packings go to biaxial_tolerance_runs/ beside the record.
Printed and written (the record, --out, default {output_dir}/bench/biaxial_tolerance.json, after
every run) per tolerance, loosest first: the largest platen-force difference to the tightest
finished run over the path (in % of its peak), before and after that peak, the band metrics and
their differences, Newton iterations, cutbacks, DEM particle-steps and the wall time; a run that
stops in Newton is a row with its error.
"""

from __future__ import annotations

import json
import logging
import time

import numpy as np
import pandas as pd

from granular_multiscale.analysis.bands import band_metrics
from granular_multiscale.dem.rve import RVESpec, prepare_packing
from granular_multiscale.drivers.fem_dem import run_fem_dem
from granular_multiscale.fem.newton import ConvergenceError

from common import bench_config, bench_parser, run_folder


def compare(runs: dict) -> list[dict]:
    """One row per finished run: its differences to the tightest finished run, its Newton cost."""
    tight = runs[min(runs)]
    f_ref = tight["load_force"].values
    peak = int(np.argmax(f_ref))
    m_ref = band_metrics(tight)
    rows = []
    for tol, ds in runs.items():
        f = ds["load_force"].values
        m = band_metrics(ds)
        rows.append({
            "tolerance": tol, "wall_s": ds.attrs["wall_s"], "against": min(runs),
            "force_diff_before_peak_pct": 100 * float(np.abs(f - f_ref)[: peak + 1].max() / f_ref.max()),
            "force_diff_after_peak_pct": 100 * float(np.abs(f - f_ref)[peak:].max() / f_ref.max()),
            "volumetric_strain_diff_pct": 100 * float(np.abs(ds["volumetric_strain"].values - tight["volumetric_strain"].values).max()
                                                      / np.abs(tight["volumetric_strain"].values).max()),
            "inclination_deg": m["inclination_deg"], "inclination_diff_deg": m["inclination_deg"] - m_ref["inclination_deg"],
            "onset_pct": 100 * m["onset_load"], "onset_diff_pct": 100 * (m["onset_load"] - m_ref["onset_load"]),
            "band_ratio": m["band_ratio"], "width_mm": 1e3 * m["width_m"],
            "newton_iterations": int(ds["newton_iterations"].sum()), "cutbacks": int(ds["cutbacks"].sum()),
            "particle_steps": float(ds.attrs["dem_particle_steps"]),
        })
    return rows


def main(argv=None) -> None:
    parser = bench_parser("biaxial_tolerance", __doc__, configfile=["config/tiny.yaml"])
    parser.add_argument("--spheres", type=int, default=100)
    parser.add_argument("--tolerances", type=float, nargs="+", default=[0.05, 0.02, 0.01])
    parser.add_argument("--segments", type=json.loads, default=None,
                        help="replace the path's segments, JSON: '[[9, 0.045]]' stops before the tiny peak")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", datefmt="%H:%M:%S")
    work = run_folder(args)
    work.mkdir(parents=True, exist_ok=True)
    config = bench_config(args.configfile, {"dem.n_spheres": args.spheres})
    path = list(config["biaxial"]["load_paths"])[0]
    if args.segments is not None:
        config["biaxial"]["load_paths"][path]["segments"] = args.segments
    measurement = parser.measurement(args, biaxial=config["biaxial"])
    packings = {}
    for name, friction in (("strong", config["dem"]["friction"]), ("weak", config["biaxial"]["weak_zone"]["dem_friction"])):
        packings[name] = work / f"packing_{args.spheres}_{name}.yade.gz"
        if not packings[name].exists():
            spec = RVESpec.from_config(config, config["seed"])
            spec.friction = float(friction)
            prepare_packing(spec, packings[name])
    runs, failed = {}, []
    for tol in sorted(args.tolerances, reverse=True):
        config["biaxial"]["dem_newton"]["tolerance"] = tol
        t0 = time.perf_counter()
        try:
            runs[tol] = run_fem_dem(config, path, [str(packings["strong"])], work / f"tol_{tol:g}.h5", None,
                                    args.workers, problem="biaxial", weak_packing=str(packings["weak"]))
            runs[tol].attrs["wall_s"] = time.perf_counter() - t0
        except ConvergenceError as error:
            failed.append({"tolerance": tol, "wall_s": time.perf_counter() - t0, "error": str(error)[:500]})
        rows = (compare(runs) if runs else []) + failed
        print(pd.DataFrame(rows).drop(columns="error", errors="ignore").to_string(index=False, float_format=lambda v: f"{v:.4g}"))
        measurement.finish(rows, args.out)  # after every tolerance: a stopped bench keeps what it measured
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
