"""FEM–ML at the paper mesh (5×5×10 hexahedra = 2000 Gauss points) on Path2 (57 steps):
wall time of the whole run with the nn tangent (NNσ + ND) and with the autodiff tangent
(exact Jacobian of NNσ), Newton iterations and the material / assembly / solve split.

The networks are material models, independent of the mesh: by default the bench uses the
models of a finished run of the config (--configfile; default config/config.yaml, whose run
writes results/models/nn_sigma.pt, nn_tangent.pt), or those of --models. When they are missing
(or with --train) it trains a quick pair on the elastoplastic reference of Path1 at the default
mesh (2×2×4), with the config's surrogate settings but --epochs epochs.
The paper needed 0.2 h for this run (Table 4); the goal here is under 10 s.

The default-scale networks (trained on Path1 of the 2×2×4 mesh and the RVE-path sets, which
reach 9 % with the set `long`) run the whole path with no point outside their training range;
networks trained on Path1 of the default mesh alone stopped at step 54 of 57, their inputs out
of range at the corner points. Networks trained on paper-mesh data (the elastoplastic
reference: its paper-mesh runs take seconds):

    .venv/bin/snakemake -j2 --configfile config/paper.yaml --config reference_material=elastoplastic \
        output_dir=results/paper_ep 'surrogate={epochs: 100, history_variables: [phi1, phi2]}' -- \
        results/paper_ep/models/nn_sigma.pt results/paper_ep/models/nn_tangent.pt \
        results/paper_ep/fem_elastoplastic/path2.h5
    .venv/bin/python bench/bench_fem_ml.py --models results/paper_ep/models \
        --reference results/paper_ep/fem_elastoplastic/path2.h5

(--reference: the top-force error against that run, per load phase, in % of its peak; add
`ensemble_size: 5` to the surrogate overrides, and another output_dir, for the ensemble row
of docs/surrogate.md.)

    .venv/bin/python bench/bench_fem_ml.py [--configfile FILE ...] [--models FOLDER] [--train] [--epochs 150]
                                           [--elements 5 5 10] [--path path2] [--reference FILE] [--out FILE]

Printed, and written to the record (--out, default {output_dir}/bench/fem_ml.json): the networks
used, and per tangent (``runs``: nn, autodiff) the wall and CPU time, the solver's split, Newton
iterations, cutbacks, the steps done and, with --reference, the top-force error per load phase.
"""

from __future__ import annotations

import logging
import os
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from granular_multiscale.data import read_run
from granular_multiscale.drivers.fem_ml import run_fem_ml
from granular_multiscale.fem.newton import ConvergenceError
from granular_multiscale.paths import load_paths_from_config
from granular_multiscale.surrogate.models import SurrogateModel

from common import bench_config, bench_parser, curve_error_pct, pipeline_models, train_elastoplastic_models


def quick_models(config: dict, folder: Path, epochs: int) -> tuple[Path, Path]:
    """Train NNσ and ND on the elastoplastic training-path reference at the default mesh."""
    t0 = time.perf_counter()
    files = train_elastoplastic_models(config, (2, 2, 4), folder, epochs=epochs, log_every=10**9)
    print(f"trained a quick NNσ + ND ({epochs} epochs) in {time.perf_counter() - t0:.0f} s")
    return files


def main(argv=None) -> dict:
    parser = bench_parser("fem_ml", __doc__)
    parser.add_argument("--models", default=None, help="folder with nn_sigma.pt and nn_tangent.pt "
                        "(default: those of the config's output_dir)")
    parser.add_argument("--train", action="store_true", help="train a quick pair even if --models has one")
    parser.add_argument("--epochs", type=int, default=150, help="epochs of the quick training")
    parser.add_argument("--elements", type=int, nargs=3, default=[5, 5, 10])
    parser.add_argument("--path", default="path2",
                        help="load path of the config, or 'monotonic': the same 57 steps loading straight to 4.5 %%")
    parser.add_argument("--reference", default=None, help="reference run of the same mesh and path: the top-force error per load phase")
    args = parser.parse_args(argv)

    logging.basicConfig(level=logging.WARNING)
    config = bench_config(args.configfile, {"reference_material": "elastoplastic"})
    torch.set_num_threads(int(config["surrogate"]["torch_threads"]))
    measurement = parser.measurement(args)
    sigma, tangent = pipeline_models(config, args.models)
    scratch = tempfile.TemporaryDirectory()
    if args.train or not (sigma.is_file() and tangent.is_file()):
        sigma, tangent = quick_models(config, Path(scratch.name), args.epochs)
        networks = f"a quick NNσ + ND trained here ({args.epochs} epochs)"
    else:
        networks = f"{sigma}, {tangent}"
    print(f"models: {networks}")
    ensemble_size = SurrogateModel.load(sigma).ensemble_size
    print(f"networks per model: {ensemble_size}" + (" (an ensemble: the mean of their predictions)" if ensemble_size > 1 else ""))

    paper = dict(config, specimen=dict(config["specimen"], elements=list(args.elements)))
    if args.path == "monotonic":  # same step count as Path2, without its reversal (timing only)
        paper["load_paths"] = dict(config["load_paths"], monotonic={"segments": [[57, 0.045]]})
    n_steps = load_paths_from_config(paper)[args.path].n_steps
    reference = read_run(args.reference) if args.reference else None
    results = {}
    for method in ("nn", "autodiff"):
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            ds, stopped = run_fem_ml(paper, args.path, sigma, tangent, method, progress=False), ""
        except ConvergenceError as error:  # report how far it got and what it cost
            ds, stopped = error.partial, str(error)
            ds.attrs["completed"] = 0  # compared with the reference on the steps it reached
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        results[method] = {
            "cpu_s": cpu,
            "completed": not stopped,
            "stopped": stopped,
            "wall_s": wall,
            "solver_s": float(ds.attrs.get("time_run_s", np.nan)),
            "material_s": float(ds.attrs.get("time_material_s", np.nan)),
            "assembly_s": float(ds.attrs.get("time_assembly_s", np.nan)),
            "solve_s": float(ds.attrs.get("time_solve_s", np.nan)),
            "newton_iterations": int(ds["newton_iterations"].sum()),
            "max_iterations_per_step": int(ds["newton_iterations"].max()),
            "cutbacks": int(ds["cutbacks"].sum()),
            "gauss_points": int(ds.sizes["gp"]),
            "ensemble_size": ensemble_size,
            "steps": n_steps,
            "steps_done": int(ds.sizes["step"]) - 1,
        }
        if reference is not None:
            results[method]["top_force_error_pct_of_peak"] = curve_error_pct(reference, ds, "top_force")
    print(f"FEM–ML {args.path}, mesh {'x'.join(map(str, args.elements))} "
          f"({results['nn']['gauss_points']} Gauss points, {n_steps} steps), torch threads "
          f"{torch.get_num_threads()}")
    print(f"{'tangent':9s} {'steps':>7s} {'wall s':>7s} {'CPU s':>6s} {'material':>8s} {'assembly':>8s} {'solve':>6s} {'Newton':>7s} "
          f"{'max/step':>8s} {'cutbacks':>8s}")
    for method, r in results.items():
        print(f"{method:9s} {r['steps_done']:3d}/{r['steps']:<3d} {r['wall_s']:7.2f} {r['cpu_s']:6.2f} {r['material_s']:8.2f} "
              f"{r['assembly_s']:8.2f} {r['solve_s']:6.2f} {r['newton_iterations']:7d} "
              f"{r['max_iterations_per_step']:8d} {r['cutbacks']:8d}")
        if r["stopped"]:
            print(f"          stopped: {r['stopped'][:160]}")
        if "top_force_error_pct_of_peak" in r:
            print("          top-force error, max % of peak: " + ", ".join(
                f"{phase} {value:.2f}" for phase, value in r["top_force_error_pct_of_peak"].items()))
    print(f"goal: under 10 s (the paper's FEM–ML run took 0.2 h); load average now {os.getloadavg()[0]:.1f} on "
          f"{os.cpu_count()} cores (CPU s is what the run itself used)")
    scratch.cleanup()
    figures = {"networks": networks, "torch_threads": torch.get_num_threads(), "runs": results}
    measurement.finish(figures, args.out)
    print(f"wrote {args.out}")
    return figures


if __name__ == "__main__":
    main()
