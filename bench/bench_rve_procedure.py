"""The RVE procedure of FEM–DEM measured against a triaxial test driven directly in YADE.

For each packing (seeds ``--seeds``, ``--spheres`` spheres, consolidated as the rule rve does;
or ``--packings`` files) it runs, one YADE process at a time:

direct tests (``granular_multiscale.studies.direct_triaxial``, continuous unless stated)
  direct            axial rate 2.5/s, servo holds σ11 = σ22 = −p, shear strains zero  (the reference)
  direct shear free the same, the servo also holds the shear stresses at 0 (the FEM's boundary condition)
  direct stops 1    the servo test, the cell stopped (velGrad = 0) for 1 step every 0.1 % axial strain
  direct stops 50   ... for 50 steps every 0.1 % (exaggerates whatever a stop does)
uniform-field FEM–DEM of one RVE (TriaxialProblem + DemMaterialPointSet of 1 point)
  fem-dem 45        smooth platens, 45 steps to 4.5 %, dem.newton.tolerance 1e-3 (the reference setting)
  fem-dem 90 / 180  90 or 180 steps
  fem-dem tol 1e-4 / tol 2e-2   other Newton tolerances (2e-2 = the project's default)
  fem-dem snap 0    no scene re-load every 10 steps (dem.snapshot_interval 0)
replays in one RVE of a strain history (``direct_triaxial`` mode replay)
  replay fem-dem stops   the FEM–DEM run's committed increments, as Host.impose does (must equal fem-dem 45)
  replay fem-dem cont    the same increments without the step at rest between them
  replay direct stops    the direct test's strain path, in 0.1 % increments with the step at rest
  replay direct cont     ... imposed continuously

Printed: q (kPa) and εv (%) at 0.5/1/2/3/4.5 % axial strain, mean ± standard deviation over the
packings; the paired difference to the direct test at 3 and 4.5 %; for the replays the largest
|σ11 or σ22 + p| / p at the increment ends (how far the path is from the other procedure's
equilibrium); the wall time of every run. The record (--out, default
{output_dir}/bench/rve_procedure.json) holds everything: the packings, every run's numbers
(``runs``, ``sensitivity``) and the printed table.

    .venv/bin/python bench/bench_rve_procedure.py [--spheres 400] [--seeds 0 1 2] [--quick] [--sensitivity]
        [--packings results/rve/packing_0.yade.gz ...] [--workdir DIR] [--out FILE]

``--quick``: only direct, direct shear free, direct stops 1, fem-dem 45 and the two FEM–DEM replays.
``--sensitivity``: also the direct test's own numerical settings (rate, damping, homoDeform,
servo interval, time step, equal lateral strains, YADE's PeriTriaxController) on the first packing. The machine
may be shared: wall times include the contention. One 400-sphere packing costs about 1 min to
consolidate and 7 min for all runs on a 2-core machine.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from granular_multiscale.dem.rve import RVESpec, prepare_packing
from granular_multiscale.studies.direct_triaxial import (
    REPORT_AT,
    DirectSpec,
    at_strains,
    fem_dem_config,
    increments_of,
    peak,
    run_direct,
)
from granular_multiscale.studies.uniform_fem_dem import run_fem_dem_uniform

from common import bench_parser

P0 = 1.0e5


def lateral_error(result: dict) -> float:
    """Largest |σ11 + p| or |σ22 + p| over p at the increment ends of a replay (its first record excluded)."""
    s = np.array([r["stress"] for r in result["records"][1:]])
    return float(np.abs(s[:, :2] + P0).max() / P0)


def runs_for(packing: str, quick: bool, log) -> dict:
    out = {}

    def direct(name, **kw):
        t0 = time.perf_counter()
        r = run_direct(DirectSpec(**kw), packing)
        r["wall"] = time.perf_counter() - t0
        out[name] = r
        log(name, r)
        return r

    def fem_dem(name, snapshot_interval=None, **kw):
        t0 = time.perf_counter()
        r = run_fem_dem_uniform(packing, fem_dem_config(**kw), snapshot_interval=snapshot_interval)
        r["wall"] = time.perf_counter() - t0
        out[name] = r
        log(name, r)
        return r

    ref = direct("direct")
    direct("direct shear free", shear="free")
    direct("direct stops 1", stop_every=0.001, stop_steps=1)
    if not quick:
        direct("direct stops 50", stop_every=0.001, stop_steps=50)
    fd = fem_dem("fem-dem 45")
    if not quick:
        fem_dem("fem-dem 90", n_steps=90)
        fem_dem("fem-dem 180", n_steps=180)
        fem_dem("fem-dem tol 1e-4", tolerance=1e-4)
        fem_dem("fem-dem tol 2e-2", tolerance=2e-2)
        fem_dem("fem-dem snap 0", snapshot_interval=0)
    rs = direct("replay fem-dem stops", mode="replay", replay_dstrain=increments_of(fd))
    s = np.array([r["stress"] for r in rs["records"][1:]])
    rs["max_diff_to_fem_dem_Pa"] = float(np.abs(s - np.asarray(fd["stress"])).max())
    direct("replay fem-dem cont", mode="replay", replay_dstrain=increments_of(fd), replay_stops=False)
    if not quick:
        direct("replay direct stops", mode="replay", replay_dstrain=increments_of(ref, 0.001))
        direct("replay direct cont", mode="replay", replay_dstrain=increments_of(ref, 0.001), replay_stops=False)
    return out


SENSITIVITY = {  # variants of the direct test (run on the first packing with --sensitivity)
    "direct rate 0.5/s": dict(strain_rate=0.5, record_every=5),
    "direct rate 1/s": dict(strain_rate=1.0, record_every=2),
    "direct damping 0": dict(damping=0.0),
    "direct damping 0.4": dict(damping=0.4),
    "direct homoDeform 1": dict(homo_deform=1),
    "direct servo every step": dict(servo_interval=1, tangent_every=50, record_every=10),
    "direct servo every 50": dict(servo_interval=50, tangent_every=2),
    "direct dt x0.5": dict(dt_factor=0.5, record_every=2),
    "direct equal lateral": dict(lateral="equal"),
    "PeriTriaxController dyn": dict(mode="peri_triax", dyn_cell=True),
    "PeriTriaxController": dict(mode="peri_triax"),
}


def fmt(values, scale, digits):
    v = np.asarray(values, dtype=float) * scale
    if len(v) == 1:
        return f"{v[0]:.{digits}f}"
    return f"{v.mean():.{digits}f}±{v.std(ddof=1):.{digits}f}"


def table(all_runs: dict[str, dict]) -> str:
    seeds = list(all_runs)
    names = list(next(iter(all_runs.values())))
    pts = "/".join(f"{100 * a:g}" for a in REPORT_AT)
    at = {s: {n: at_strains(r) for n, r in runs.items()} for s, runs in all_runs.items()}
    lines = [f"packings: {', '.join(seeds)}; mean ± standard deviation over {len(seeds)} packing(s)", "",
             f"{'run':22s} | q (kPa) at {pts} % axial strain | εv (%) at the same | peak q (kPa) at (%) | "
             f"replay |σlat+p|/p | wall (s)"]
    for name in names:
        q = " ".join(fmt([at[s][name]["q"][i] for s in seeds], 1e-3, 1) for i in range(len(REPORT_AT)))
        ev = " ".join(fmt([at[s][name]["volumetric_strain"][i] for s in seeds], 100, 3) for i in range(len(REPORT_AT)))
        pk = [peak(all_runs[s][name]) for s in seeds]
        pks = f"{fmt([p[1] for p in pk], 1e-3, 1)} at {fmt([p[0] for p in pk], 100, 2)}"
        lat = (fmt([lateral_error(all_runs[s][name]) for s in seeds], 100, 2) + " %"
               if name.startswith("replay") else "")
        wall = fmt([all_runs[s][name]["wall"] for s in seeds], 1, 0)
        lines.append(f"{name:22s} | {q} | {ev} | {pks} | {lat} | {wall}")
    refs = [r for r in ("direct", "direct shear free") if r in names]
    lines += ["", "paired differences (run − reference, same packing), mean ± standard deviation over the packings:",
              f"{'run':22s} | " + " | ".join(f"Δq (kPa) at 2/3/4.5 % vs {r} | Δεv (%) at 2/3/4.5 % vs {r}" for r in refs)]
    for name in names:
        cells = []
        for r in refs:
            cells.append(" ".join(fmt([at[s][name]["q"][i] - at[s][r]["q"][i] for s in seeds], 1e-3, 1) for i in (2, 3, 4)))
            cells.append(" ".join(fmt([at[s][name]["volumetric_strain"][i] - at[s][r]["volumetric_strain"][i]
                                       for s in seeds], 100, 3) for i in (2, 3, 4)))
        lines.append(f"{name:22s} | " + " | ".join(cells))
    return "\n".join(lines)


def sensitivity_table(runs: dict, key: str) -> str:
    lines = [f"sensitivity of the direct test, packing {key}:",
             f"{'run':24s} | q (kPa) at {'/'.join(f'{100 * a:g}' for a in REPORT_AT)} % | εv (%) at the same | "
             "servo error max (% of p) | wall (s)"]
    for name, r in runs.items():
        a = at_strains(r)
        lines.append(f"{name:24s} | {' '.join(f'{x / 1e3:.1f}' for x in a['q'])} | "
                     f"{' '.join(f'{100 * x:.3f}' for x in a['volumetric_strain'])} | "
                     f"{100 * r.get('servo_error_max', float('nan')):.2f} | {r['wall']:.0f}")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = bench_parser("rve_procedure", __doc__)
    parser.add_argument("--spheres", type=int, default=400)
    parser.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 2])
    parser.add_argument("--packings", nargs="*", default=[], help="consolidated packings to use as well (read only)")
    parser.add_argument("--workdir", default=str(Path(tempfile.gettempdir()) / "bench_rve_procedure"),
                        help="where packings made here are kept (reused when present)")
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--sensitivity", action="store_true",
                        help="also run the direct-test variants of SENSITIVITY on the first packing")
    args = parser.parse_args(argv)
    measurement = parser.measurement(args)

    t_start = time.perf_counter()
    work = Path(args.workdir)
    work.mkdir(parents=True, exist_ok=True)
    packings = {}
    for seed in args.seeds:
        path = work / f"packing_n{args.spheres}_s{seed}.yade.gz"
        if not path.exists():
            t0 = time.perf_counter()
            s = prepare_packing(RVESpec(n_spheres=args.spheres, seed=seed), path)
            print(f"packing seed {seed}: {args.spheres} spheres consolidated in {time.perf_counter() - t0:.0f} s, "
                  f"porosity {s['porosity']:.4f}", flush=True)
        packings[f"seed {seed} ({args.spheres})"] = str(path)
    for p in args.packings:
        packings[p] = p

    def log(name, r):
        a = at_strains(r)
        extra = ""
        if "servo_error_max" in r:
            extra = f", servo error max {100 * r['servo_error_max']:.2f} % of p"
        if "max_diff_to_fem_dem_Pa" in r:
            extra = f", max |stress − FEM–DEM| {r['max_diff_to_fem_dem_Pa']:.2g} Pa"
        if "material_evaluations" in r:
            extra = f", {int(np.sum(r['material_evaluations']))} RVE evaluations"
        print(f"  {name:22s} {r['wall']:6.1f} s: q {' '.join(f'{x / 1e3:.1f}' for x in a['q'])} kPa, "
              f"εv {' '.join(f'{100 * x:.3f}' for x in a['volumetric_strain'])} %{extra}", flush=True)

    all_runs = {}
    for key, path in packings.items():
        print(f"{key}: {path}", flush=True)
        all_runs[key] = runs_for(path, args.quick, log)
    sens = {}
    if args.sensitivity:
        key, path = next(iter(packings.items()))
        print(f"sensitivity, {key}:", flush=True)
        sens = {"direct": all_runs[key]["direct"], "direct shear free": all_runs[key].get("direct shear free")}
        sens = {k: v for k, v in sens.items() if v is not None}
        for name, kw in SENSITIVITY.items():
            t0 = time.perf_counter()
            r = run_direct(DirectSpec(**kw), path)
            r["wall"] = time.perf_counter() - t0
            sens[name] = r
            log(name, r)
    print()
    print(table(all_runs))
    if sens:
        print()
        print(sensitivity_table(sens, key))
    print(f"\ntotal wall time {time.perf_counter() - t_start:.0f} s")
    # the runs' numbers without their per-step records
    slim = {k: {n: {kk: vv for kk, vv in r.items() if kk not in ("records", "dstrain", "strain", "stress")}
                | {"at": at_strains(r), "peak": peak(r)} for n, r in runs.items()}
            for k, runs in all_runs.items()}
    slim_sens = {n: {kk: vv for kk, vv in r.items() if kk != "records"} | {"at": at_strains(r)} for n, r in sens.items()}
    measurement.finish({"packings": packings, "runs": slim, "table": table(all_runs), "sensitivity": slim_sens},
                       args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
