"""The whole pipeline, measured: `snakemake -j2 all` and its report at one scale, and what that
run wrote (every rule's wall time, the headline, the tables), as one record.

    python bench/bench_all.py                              # runs all and the report, then records
    python bench/bench_all.py --wall-s 2935 --setup-s 59 --report-s 3   # records a run made by hand

With ``--wall-s`` the workflow is not run: the record takes the times given (measured by whoever
ran it, e.g. the two README commands under `time`) and reads the finished output folder.
``--configfile`` picks the scale as for snakemake (config/config.yaml and the files merged over it).

The README's and docs' measured blocks are rendered from this record (bench/update_docs.py);
the default record (--out) is docs/measured/all_default.json, not one under the output_dir."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from granular_multiscale.analysis.quantities import equivalent_shear_strain
from granular_multiscale.analysis.tables import benchmark_seconds
from granular_multiscale.data import read_run
from granular_multiscale.plan import Plan

from common import ROOT, bench_parser


def timed(command: list[str]) -> float:
    started = time.perf_counter()
    subprocess.run(command, cwd=ROOT, check=True)
    return time.perf_counter() - started


def rule_wall_times(output_dir: Path) -> dict[str, float]:
    """Every rule's wall seconds from its Snakemake benchmark file, keyed by the file's name
    under benchmarks/ without .tsv (``fem_dem/path2``)."""
    folder = output_dir / "benchmarks"
    return {str(path.relative_to(folder).with_suffix("")): round(benchmark_seconds(path), 1)
            for path in sorted(folder.rglob("*.tsv"))}


#: the run's tables a record keeps (the per-Gauss-point ones stay in the output folder)
TABLES = ("speedup.csv", "accuracy.csv", "surrogate_cost.csv", "validation_by_phase.csv", "calibration.csv",
          "spread_scale.csv", "biaxial_bands.csv", "footing.csv", "rve_angles.csv", "visited_states.csv",
          "biaxial/surrogate_biaxial.csv", "footing/surrogate_footing.csv", "biaxial/calibration_biaxial.csv",
          "footing/calibration_footing.csv")


def tables(plan: Plan) -> dict[str, list[dict]]:
    """The run's summary tables (those of TABLES that it wrote), as rows."""
    files = {name: Path(plan.layout.table(name)) for name in TABLES}
    return {name: json.loads(pd.read_csv(file).to_json(orient="records")) for name, file in files.items() if file.is_file()}


def dem_work(plan: Plan) -> dict[str, dict]:
    """DEM work of every FEM–DEM run of the triaxial load paths and the problems, and of every
    RVE-path set: particle-steps, DEM CPU seconds and wall seconds, from the run files' attrs."""
    files = {f"fem_dem/{path}": plan.reference_run(path) for path in (plan.training_path, plan.validation_path)}
    files |= {f"{problem}/{case}": plan.problem_run(problem, case)
              for problem, cases in plan.problem_cases.items() for case in cases}
    files |= {f"rve_paths/{name}": plan.layout.rve_paths(name) for name in plan.rve_path_sets}
    work = {}
    for key, file in files.items():
        if Path(file).is_file():
            attrs = read_run(file, required=()).attrs
            if "dem_particle_steps" in attrs:
                work[key] = {"particle_steps": int(attrs["dem_particle_steps"]),
                             "cpu_s": round(float(attrs["dem_cpu_time_s"]), 1),
                             "wall_s": round(float(attrs.get("dem_wall_time_s", attrs.get("rve_paths_wall_time_s", 0))), 1)}
    return work


def rve_path_sets(plan: Plan) -> dict[str, dict]:
    """What each RVE-path set holds: trajectories per family, steps, evaluations, lost contacts,
    and the largest axial and lateral strains (% , compression positive) and equivalent shear
    strain ε_s its valid states reach."""
    sets = {}
    for name in plan.rve_path_sets:
        file = Path(plan.layout.rve_paths(name))
        if not file.is_file():
            continue
        run = read_run(file, required=("strain",))
        strain = run["strain"].where(run["valid"]) if "valid" in run else run["strain"]
        families = pd.Series(run["family"].values.astype(str)).value_counts()
        sets[name] = {"trajectories": int(run.attrs["n_trajectories"]), "steps": int(run.attrs["n_steps"]),
                      "evaluations": int(run.attrs["rve_evaluations"]), "lost_contact": int(run.attrs["n_lost_contact"]),
                      "families": {family: int(n) for family, n in families.items()},
                      "largest_axial_strain_pct": round(100 * float(abs(strain.isel(comp=2)).max()), 2),
                      "largest_lateral_strain_pct": round(100 * float(abs(strain.isel(comp=[0, 1])).max()), 2),
                      "largest_shear_strain_pct": round(100 * float(np.nanmax(equivalent_shear_strain(strain.values))), 2)}
    return sets


def main(argv=None) -> int:
    # the default record is the one the README's and docs' measured blocks are rendered from
    parser = bench_parser("all", __doc__, out=ROOT / "docs" / "measured" / "all_default.json")
    parser.add_argument("--wall-s", type=float, help="wall seconds of `snakemake -j2 all` run elsewhere (then nothing is run)")
    parser.add_argument("--setup-s", type=float, help="wall seconds of envs/setup.sh before it, if measured")
    parser.add_argument("--report-s", type=float, help="wall seconds of `snakemake --report` after it")
    parser.add_argument("--note", default="", help="what else ran on the machine meanwhile, where it was run")
    args = parser.parse_args(argv)

    output_dir = ROOT / args.config["output_dir"]
    plan = Plan(dict(args.config, output_dir=str(output_dir)))
    # with --wall-s the load averages are those when the record was made, not during the run
    measurement = parser.measurement(args, recorded_after_the_run=args.wall_s is not None)
    if args.wall_s is None:
        overlays = ["--configfile", *args.configfile] if args.configfile else []
        snakemake = [sys.executable, "-m", "snakemake"]
        wall = timed([*snakemake, "-j2", *overlays, "--", "all"])
        report = timed([*snakemake, *overlays, "--report", str(output_dir / "report.html"), "--", "all"])
        setup = args.setup_s
    else:
        wall, report, setup = args.wall_s, args.report_s, args.setup_s
    headline_path = Path(plan.layout.table("headline.json"))
    if not headline_path.is_file():
        print(f"{headline_path} missing: the run did not finish", file=sys.stderr)
        return 1
    headline = json.loads(headline_path.read_text())
    headline.pop("display", None)
    figures = {"note": args.note, "all_wall_s": round(wall, 1),
               "setup_s": None if setup is None else round(setup, 1),
               "report_s": None if report is None else round(report, 1),
               "rules_wall_s": rule_wall_times(output_dir), "dem_work": dem_work(plan),
               "rve_paths": rve_path_sets(plan),
               "headline": headline, "tables": tables(plan)}
    measurement.finish(figures, args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
