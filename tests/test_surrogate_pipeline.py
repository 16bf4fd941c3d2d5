"""The chain dataset -> training -> FEM–ML -> metrics from Snakemake, tiny scale, elastoplastic reference."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from granular_multiscale.data import read_run
from granular_multiscale.surrogate.dataset import read_dataset, split_of
from granular_multiscale.surrogate.models import SurrogateModel

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def tiny_chain(tmp_path_factory):
    out = tmp_path_factory.mktemp("surrogate") / "tiny"
    targets = [f"{out}/tables/fem_ml_curve_errors.csv"]
    # NNσ and ND as ensembles of two: the ensemble path through the rules, model files and figures
    cmd = [sys.executable, "-m", "snakemake", "-j2", "--configfile", "config/tiny.yaml",
           "--config", "reference_material=elastoplastic", f"output_dir={out}", "surrogate={ensemble_size: 2}",
           "--", *targets]
    result = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, result.stderr[-4000:]
    return out


@pytest.mark.slow
def test_dataset_and_models(tiny_chain):
    out = tiny_chain
    train, heldout = read_dataset(out / "dataset/train.h5"), read_dataset(out / "dataset/heldout.h5")
    assert (train.sizes["gp"], heldout.sizes["gp"]) == (12, 4)  # 75/25 of 16 Gauss points
    assert set(split_of(train)["train"]) == set(train.gp.values)
    assert not set(train.gp.values) & set(heldout.gp.values)
    sigma = SurrogateModel.load(out / "models/nn_sigma.pt")
    assert sigma.kind == "sigma" and sigma.history == ("phi1", "phi2")  # config/tiny.yaml
    assert sigma.config["surrogate"]["history_variables"] == ["phi1", "phi2"]
    assert SurrogateModel.load(out / "models/nn_tangent_nohist.pt").feature_names[-1] == "strain_12"
    assert sigma.ensemble_size == 2 and len(set(sigma.training["member_seeds"])) == 2
    losses = pd.read_csv(out / "training/sigma.csv")
    for _, member in losses.groupby("member"):
        assert len(member) == sigma.config["surrogate"]["epochs"]
        assert member.heldout_loss.iloc[-1] < 0.5 * member.heldout_loss.iloc[0]
    mae = pd.read_csv(out / "tables/surrogate_training_mae.csv")
    assert set(mae.network) == {"sigma", "tangent", "sigma_nohist", "tangent_nohist"}
    assert (out / "training/sigma_loss.png").stat().st_size > 5000
    for rule in ("dataset", "train_sigma", "metrics"):
        assert (out / f"benchmarks/surrogate/{rule}.tsv").is_file()


@pytest.mark.slow
def test_fem_ml_runs_and_metrics(tiny_chain):
    out = tiny_chain
    reference = read_run(out / "fem_elastoplastic/path2.h5")
    ml = read_run(out / "fem_ml/path2.h5")
    nohist = read_run(out / "fem_ml_nohist/path2.h5")
    assert ml.attrs["method"].startswith("fem_ml_") and "nohist" not in ml.attrs["method"]
    assert nohist.attrs["method"].startswith("fem_ml_nohist_")
    assert ml.sizes["step"] == reference.sizes["step"] and np.isfinite(ml.stress.values).all()
    assert "out_of_range_points" in ml and (ml.out_of_range_points.values >= 0).all()
    # the surrogate starts where the reference starts (anchored initial state): same consolidated force
    assert ml.top_force.values[0] == pytest.approx(reference.top_force.values[0], rel=1e-6)
    curves = pd.read_csv(out / "tables/fem_ml_curve_errors.csv")
    assert set(curves.run) == {"fem_ml", "fem_ml_nohist"} and set(curves.path) == {"path1", "path2"}
    force = curves[(curves.quantity == "top_force") & (curves.phase == "all")].set_index(["run", "path"])
    # the numbers in the table are those of the files
    err = np.abs(ml.top_force.values - reference.top_force.values)
    assert force.loc[("fem_ml", "path2"), "max_abs_error"] == pytest.approx(err.max())
    # even 16 Gauss points and seconds of training follow the reference within a fraction of its peak
    assert force.loc[("fem_ml", "path1"), "max_error_percent_of_peak"] < 25.0
    newton = pd.read_csv(out / "tables/fem_ml_newton_iterations.csv")
    assert {"iterations_nn", "iterations_autodiff", "iterations_reference"} <= set(newton.columns)
    assert len(newton) == reference.sizes["step"]
    by_gp = pd.read_csv(out / "tables/fem_ml_stress_error_by_gp.csv")
    assert set(by_gp.split) == {"train", "heldout"} and len(by_gp) == 2 * 2 * 16
