"""Benchmark of the DEM material points (YADE RVEs).

1. Seconds per RVE evaluation against sphere count (default 100, 300, 1000): one host with
   ``--rves`` RVEs of a consolidated packing, a typical load-step increment (axial −1.05e-3,
   lateral +0.3e-3) imposed ``--trials`` times from the converged state (Newton trials with
   rollback), then committed. Reports wall and CPU seconds per RVE evaluation, µs per
   particle-step, the fork/transfer overhead per trial and, for comparison, what a
   serialisation-based rollback would cost (sceneToString + stringToScene + the collider's
   rebuild on the first step, per RVE).
2. 1 → 2 local workers at the default scale: ``--speedup-steps`` steps of path1 with the
   default config (128 RVEs), once with one worker and once with two; wall time of the steps
   and the speedup.
3. Projection of a default-scale path from 2.: seconds per load step and evaluation.

    .venv/bin/python bench/bench_dem.py [--sizes 100 300 1000] [--rves 8] [--trials 3]
                                        [--speedup-steps 3] [--skip-speedup] [--configfile FILE ...] [--out FILE]

Printed, and written to the record (--out, default {output_dir}/bench/dem.json): 1. per sphere
count (``per_size``), 2. and 3. (``speedup``). The DEM settings and the default-scale problem come
from the config (--configfile, default config/config.yaml). The machine may be shared: CPU seconds
(process time of the RVE stepping) are what an idle machine would take; wall seconds include the
contention.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from granular_multiscale.dem.material import DemMaterialPointSet
from granular_multiscale.dem.rve import RVESpec, prepare_packing
from granular_multiscale.dem.yade_env import child_env

from common import bench_parser

SETTINGS_KEYS = ("strain_rate", "min_steps", "max_steps", "damping")
INCREMENT = np.array([3.0e-4, 3.0e-4, -1.05e-3, 0.0, 0.0, 0.0])

SERIALISATION = """
import json, sys, time
from granular_multiscale.dem.yade_env import import_yade
O = import_yade()
O.load(sys.argv[1])
from yade.minieigenHP import Matrix3
out = {"save": [], "load": [], "first_step": [], "step": []}
for _ in range(5):
    t0 = time.perf_counter(); s = O.sceneToString(); t1 = time.perf_counter()
    O.stringToScene(s); t2 = time.perf_counter()
    O.step(); t3 = time.perf_counter()
    O.step(); t4 = time.perf_counter()
    out["save"].append(t1 - t0); out["load"].append(t2 - t1); out["first_step"].append(t3 - t2); out["step"].append(t4 - t3)
out = {k: sorted(v)[len(v) // 2] for k, v in out.items()}
out["bytes"] = len(s)
print(json.dumps(out))
"""


def per_size(config: dict, n_spheres: int, n_rves: int, trials: int, workdir: Path) -> dict:
    settings = {k: config["dem"][k] for k in SETTINGS_KEYS}
    path = workdir / f"packing_{n_spheres}.yade.gz"
    t0 = time.perf_counter()
    summary = prepare_packing(RVESpec(n_spheres=n_spheres, seed=0), path)
    prep = time.perf_counter() - t0
    strain = np.tile(INCREMENT, (n_rves, 1))
    with DemMaterialPointSet(n_rves, [path], settings, n_workers=1) as m:
        walls = []
        for k in range(trials):
            t0 = time.perf_counter()
            m.evaluate(strain * (1 + 1e-3 * k))  # distinct trials: each runs the DEM
            walls.append(time.perf_counter() - t0)
        info = dict(m._step)
        m.commit()
    evaluations = trials * n_rves
    ser = json.loads(subprocess.run([sys.executable, "-c", SERIALISATION, str(path)], env=child_env(),
                                    capture_output=True, text=True, check=True).stdout.strip().splitlines()[-1])
    dem_wall_per_eval = info["dem_time"] / evaluations
    result = {
        "n_spheres": n_spheres,
        "consolidation_s": prep,
        "consolidation_steps": summary["steps"],
        "porosity": summary["porosity"],
        "dem_steps_per_evaluation": int(info["dem_steps_max"]) + 1,
        "wall_s_per_evaluation": float(np.sum(walls)) / evaluations,
        "dem_wall_s_per_evaluation": dem_wall_per_eval,
        "dem_cpu_s_per_evaluation": info["dem_cpu_time"] / evaluations,
        "cpu_us_per_particle_step": 1e6 * info["dem_cpu_time"] / info["particle_steps"],
        "overhead_s_per_trial": info["overhead_time"] / trials,
        "overhead_share": info["overhead_time"] / info["material_time"],
        "serialisation_rollback_s_per_rve": ser["save"] + ser["load"] + (ser["first_step"] - ser["step"]),
        "serialisation_share_if_used": (ser["save"] + ser["load"] + ser["first_step"] - ser["step"])
        / (ser["save"] + ser["load"] + ser["first_step"] - ser["step"] + dem_wall_per_eval),
        "scene_bytes": ser["bytes"],
    }
    print(f"{n_spheres:5d} spheres: {result['dem_steps_per_evaluation']} DEM steps per evaluation, "
          f"{result['wall_s_per_evaluation']:.3f} s wall / {result['dem_cpu_s_per_evaluation']:.3f} s CPU per RVE "
          f"evaluation, {result['cpu_us_per_particle_step']:.2f} µs per particle-step; fork/transfer "
          f"{1e3 * result['overhead_s_per_trial']:.1f} ms per trial of {n_rves} RVEs "
          f"({100 * result['overhead_share']:.1f} %); a serialising rollback would add "
          f"{1e3 * result['serialisation_rollback_s_per_rve']:.1f} ms per RVE "
          f"({100 * result['serialisation_share_if_used']:.0f} % of an evaluation); consolidation {prep:.1f} s",
          flush=True)
    return result


def speedup(config: dict, steps: int, workdir: Path) -> dict:
    """The default-scale problem for `steps` steps of path1 with 1 and 2 local workers."""
    from granular_multiscale.dem.run import prepare_rves
    from granular_multiscale.drivers.fem_dem import dem_newton_config
    from granular_multiscale.fem.triaxial import TriaxialProblem
    from granular_multiscale.paths import LoadPath, load_paths_from_config

    packing = workdir / "default_packing.yade.gz"
    prepare_rves(config, [str(packing)], str(workdir / "default_summary.json"))
    cfg = dem_newton_config(config)
    full = load_paths_from_config(cfg)["path1"]
    axial = full.axial_strain()[steps]
    path = LoadPath("path1_start", ((steps, float(axial)),))
    problem = TriaxialProblem.from_config(cfg)
    out = {"steps": steps, "gauss_points": problem.n_material_points, "n_spheres": cfg["dem"]["n_spheres"]}
    for workers in (1, 2):
        with DemMaterialPointSet.from_config(cfg, problem.n_material_points, [packing], n_workers=workers) as m:
            t0 = time.perf_counter()
            ds = problem.run(m, path, method="dem", progress=False)
            wall = time.perf_counter() - t0
            split = m.time_split()
        out[f"wall_s_{workers}"] = wall
        out[f"evaluations_{workers}"] = int(ds.material_evaluations.values.sum())
        out[f"dem_cpu_s_{workers}"] = split["dem_cpu_time"]
        out[f"not_stepping_share_{workers}"] = 1 - split["dem_time"] / wall
        out[f"stress_{workers}"] = ds.stress.values
        print(f"{workers} worker(s): {steps} steps in {wall:.1f} s ({out[f'evaluations_{workers}']} evaluations, "
              f"{split['dem_cpu_time']:.1f} CPU s of DEM stepping, not stepping {100 * out[f'not_stepping_share_{workers}']:.1f} %)",
              flush=True)
    out["identical"] = bool(np.array_equal(out.pop("stress_1"), out.pop("stress_2")))
    out["speedup"] = out["wall_s_1"] / out["wall_s_2"]
    evals = out["evaluations_2"]
    out["s_per_evaluation_2_workers"] = out["wall_s_2"] / evals
    out["cpu_s_per_evaluation"] = out["dem_cpu_s_2"] / evals
    print(f"1 -> 2 workers: {out['speedup']:.2f}x (identical results: {out['identical']}); "
          f"{out['s_per_evaluation_2_workers']:.1f} s per evaluation of all {out['gauss_points']} RVEs with 2 workers "
          f"({out['cpu_s_per_evaluation']:.1f} CPU s)", flush=True)
    return out


def main(argv=None) -> dict:
    parser = bench_parser("dem", __doc__)
    parser.add_argument("--sizes", type=int, nargs="+", default=[100, 300, 1000])
    parser.add_argument("--rves", type=int, default=8)
    parser.add_argument("--trials", type=int, default=3)
    parser.add_argument("--speedup-steps", type=int, default=3)
    parser.add_argument("--skip-speedup", action="store_true")
    args = parser.parse_args(argv)
    measurement = parser.measurement(args)
    figures = {"per_size": [], "speedup": None}
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.sizes:
            figures["per_size"].append(per_size(args.config, n, args.rves, args.trials, Path(tmp)))
        if not args.skip_speedup:
            figures["speedup"] = speedup(args.config, args.speedup_steps, Path(tmp))
    measurement.finish(figures, args.out)
    print(f"wrote {args.out}")
    return figures


if __name__ == "__main__":
    main()
