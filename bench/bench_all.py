"""The whole pipeline, measured: `snakemake -j2 all` and its report at one scale, and what that
run wrote (every rule's wall time, the headline, the tables), as one record.

    python bench/bench_all.py                              # runs all and the report, then records
    python bench/bench_all.py --wall-s 2935 --setup-s 59 --report-s 3   # records a run made by hand

With ``--wall-s`` the workflow is not run: the record takes the times given (measured by whoever
ran it, e.g. the two README commands under `time`) and reads the finished output folder.

The README's and docs' measured blocks are rendered from this record (bench/update_docs.py);
the default record is docs/measured/all_default.json."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd

from granular_multiscale.analysis.tables import benchmark_seconds
from granular_multiscale.config import load_config
from granular_multiscale.data import read_run

from common import ROOT, Measurement, config_difference


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
          "biaxial_bands.csv", "footing.csv", "rve_angles.csv", "visited_states.csv",
          "biaxial/surrogate_biaxial.csv", "footing/surrogate_footing.csv")


def tables(output_dir: Path) -> dict[str, list[dict]]:
    """The run's summary tables (those of TABLES that it wrote), as rows."""
    folder = output_dir / "tables"
    return {name: json.loads(pd.read_csv(folder / name).to_json(orient="records"))
            for name in TABLES if (folder / name).is_file()}


def reference_work(output_dir: Path) -> dict[str, int]:
    """DEM particle-steps of every FEM–DEM run of the triaxial load paths."""
    work = {}
    for path in sorted((output_dir / "fem_dem").glob("*.h5")):
        run = read_run(path)
        if "dem_particle_steps" in run.attrs:
            work[path.stem] = int(run.attrs["dem_particle_steps"])
    return work


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--configfile", help="the scale's config (default config/config.yaml), as for snakemake")
    parser.add_argument("--wall-s", type=float, help="wall seconds of `snakemake -j2 all` run elsewhere (then nothing is run)")
    parser.add_argument("--setup-s", type=float, help="wall seconds of envs/setup.sh before it, if measured")
    parser.add_argument("--report-s", type=float, help="wall seconds of `snakemake --report` after it")
    parser.add_argument("--note", default="", help="what else ran on the machine meanwhile, where it was run")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "measured" / "all_default.json")
    args = parser.parse_args(argv)

    config = load_config(args.configfile)
    defaults = load_config()
    output_dir = ROOT / config["output_dir"]
    # with --wall-s the load averages are those when the record was made, not during the run
    measurement = Measurement("all", {"configfile": args.configfile, "config_difference": config_difference(config, defaults),
                                      "recorded_after_the_run": args.wall_s is not None})
    if args.wall_s is None:
        overlays = ["--configfile", args.configfile] if args.configfile else []
        snakemake = [sys.executable, "-m", "snakemake"]
        wall = timed([*snakemake, "-j2", *overlays, "--", "all"])
        report = timed([*snakemake, *overlays, "--report", str(output_dir / "report.html"), "--", "all"])
        setup = args.setup_s
    else:
        wall, report, setup = args.wall_s, args.report_s, args.setup_s
    headline_path = output_dir / "tables" / "headline.json"
    if not headline_path.is_file():
        print(f"{headline_path} missing: the run did not finish", file=sys.stderr)
        return 1
    headline = json.loads(headline_path.read_text())
    headline.pop("display", None)
    figures = {"note": args.note, "all_wall_s": round(wall, 1),
               "setup_s": None if setup is None else round(setup, 1),
               "report_s": None if report is None else round(report, 1),
               "rules_wall_s": rule_wall_times(output_dir), "dem_particle_steps": reference_work(output_dir),
               "headline": headline, "tables": tables(output_dir)}
    measurement.finish(figures, args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
