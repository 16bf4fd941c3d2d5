"""Does an ensemble's spread say which points it gets wrong? Members fitted to all the data
(``surrogate.ensemble_resampling: none``, members differ by their seeds) against members fitted to
bootstrap samples of the training trajectories (``trajectories``), measured on the analytic
elastoplastic model (no YADE, about a minute):

    .venv/bin/python bench/bench_ensemble_resampling.py [--seeds 0 1] [--epochs 200] [--members 5]

Training: material-point trajectories of the training path, lateral strain ratio 0.3–0.45 and
shears within ±5 % of the axial strain (``surrogate.synthetic``). Test: other trajectories with
a ratio 0.15–0.6 and shears within ±15 %, so that some lie inside the training data and some
well outside it. Per load step, across the test points: Spearman's rank correlation between the
members' spread ‖std σ‖ and the ensemble's error ‖σ − σ_ref‖ (and, for comparison, between the
distance to the training states, what adaptive.indicator off_training uses, and that error), and
the ratio error / spread.
Recorded (--out, default {output_dir}/bench/ensemble_resampling.json) per resampling and
training seed: the median over the steps of both, the stress MAE on the test points, and the
share of the test points whose error exceeds twice their spread (a spread too small to warn).
"""

from __future__ import annotations

import logging
import time

import numpy as np
import torch

from granular_multiscale.analysis.calibration import spearman
from granular_multiscale.config import validate_config
from granular_multiscale.materials.elastoplastic import Elastoplastic
from granular_multiscale.novelty import TrainingStates
from granular_multiscale.paths import load_paths_from_config
from granular_multiscale.surrogate.dataset import build_dataset, features, targets
from granular_multiscale.surrogate.synthetic import material_point_run, triaxial_strain_paths
from granular_multiscale.surrogate.training import train

from common import bench_parser

RESAMPLINGS = ("none", "trajectories")


def trajectories(config: dict, n_points: int, seed: int, lateral_ratio, shear: float):
    """A material-point run of the elastoplastic model along `n_points` triaxial-like strain paths."""
    path = load_paths_from_config(config)[config["training_path"]]
    strain = triaxial_strain_paths(path, n_points, seed=seed, lateral_ratio=lateral_ratio, shear=shear)
    return material_point_run(Elastoplastic.from_config(n_points, config), strain, path)


def spread_distance_and_error(model, test) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """[steps, points] the members' spread, the distance to the training states (over the radius
    the training states are within, ``novelty``) and the ensemble's error on the test dataset (Pa)."""
    raw = features(test, model.history)
    x = torch.as_tensor(raw, dtype=torch.float32)
    with torch.no_grad():
        members = np.stack([m(x).double().numpy() for m in model.members])  # [K, samples, 6]
    error = np.linalg.norm(members.mean(axis=0) - targets(test, "sigma"), axis=-1)
    spread = np.linalg.norm(members.std(axis=0), axis=-1)
    states = TrainingStates(model.training_states, radius=model.training_radius)
    distance = states.distance(raw) / states.radius
    shape = (test.sizes["step"], test.sizes["gp"])  # features order samples step-major
    return spread.reshape(shape), distance.reshape(shape), error.reshape(shape)


def median_rho(indicator: np.ndarray, error: np.ndarray) -> tuple[float, float]:
    """Over the loaded steps (step 0 is the fresh state, every member exact, nothing to rank): the
    median of the per-step Spearman ρ between indicator and error, and the share of steps with ρ ≥ 0.5."""
    rho = np.array([spearman(i, e) for i, e in zip(indicator[1:], error[1:])])
    return float(np.nanmedian(rho)), float(np.nanmean(rho >= 0.5))


def measure(spread: np.ndarray, distance: np.ndarray, error: np.ndarray) -> dict:
    ratio = error[1:] / np.maximum(spread[1:], 1e-12)
    (rho, above), (rho_distance, _) = median_rho(spread, error), median_rho(distance, error)
    return {"spearman_median": rho, "spearman_steps_above_0.5": above, "distance_spearman_median": rho_distance,
            "error_over_spread_median": float(np.median(ratio)),
            "share_error_above_twice_spread": float(np.mean(ratio > 2.0)),
            "stress_mae_kpa": 1e-3 * float(error[1:].mean())}


def main(argv=None) -> None:
    parser = bench_parser("ensemble_resampling", __doc__)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1], help="training seeds (independent trainings)")
    parser.add_argument("--epochs", type=int, default=200)
    parser.add_argument("--members", type=int, default=5, help="surrogate.ensemble_size")
    parser.add_argument("--points", type=int, default=32, help="training trajectories (and as many test ones)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    measurement = parser.measurement(args)
    config = validate_config({"reference_material": "elastoplastic"})
    train_ds, heldout_ds = build_dataset(trajectories(config, args.points, 1, (0.3, 0.45), 0.05), 0.75, seed=0)
    test, _ = build_dataset(trajectories(config, args.points, 2, (0.15, 0.6), 0.15), 0.99, seed=0)
    rows = []
    for resampling in RESAMPLINGS:
        for seed in args.seeds:
            settings = dict(config["surrogate"], epochs=args.epochs, learning_rate=3e-3, ensemble_size=args.members,
                            ensemble_resampling=resampling, log_every=args.epochs)
            t0 = time.perf_counter()
            model, _, _ = train(train_ds, heldout_ds, "sigma", settings, seed)
            row = {"resampling": resampling, "seed": seed, "train_s": time.perf_counter() - t0,
                   **measure(*spread_distance_and_error(model, test))}
            rows.append(row)
            print(", ".join(f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()))
    measurement.finish({"test_points": test.sizes["gp"], "rows": rows}, args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
