"""Training of NNσ and ND: seeded, deterministic on the CPU, every hyperparameter from the config.

Adam on the min–max scaled data (MAE loss by default, paper Table 3), mini-batches drawn
by a seeded generator; the held-out Gauss points give the validation loss of every epoch
but never choose anything (the final weights are those of the last epoch). Outputs:

* the :class:`~.models.SurrogateModel` (weights, scaling, names, config, training summary),
* the loss history per epoch (train and held-out, on the scaled targets),
* the final MAE of every target component in physical units on the train and held-out points.
"""

from __future__ import annotations

import logging
import time

import numpy as np
import pandas as pd
import torch
import xarray as xr

from torch.func import jvp

from ..atomic import atomic_path
from ..history import accumulated_from_sequence
from ..tensors import ENGINEERING_FACTOR, tangent_from_upper
from .dataset import features, history_selection, scaling, target_names, targets
from .models import SurrogateModel, trial_features

_KIND_INDEX = {"sigma": 0, "tangent": 1}


class TrainingError(RuntimeError):
    """Training cannot run or diverged; the message names the config key or the epoch."""


def model_seed(seed: int, kind: str, use_history: bool) -> int:
    """Distinct, reproducible seed per network (NNσ, ND, with and without history)."""
    return int(np.random.SeedSequence([int(seed), _KIND_INDEX[kind], int(bool(use_history))]).generate_state(1)[0])


def _device(settings: dict) -> torch.device:
    name = settings.get("device", "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise TrainingError("config key 'surrogate.device' is 'cuda' but torch sees no CUDA device; use 'cpu'")
    return torch.device(name)


def _loss_fn(name: str):
    if name == "mae":
        return torch.nn.functional.l1_loss
    if name == "mse":
        return torch.nn.functional.mse_loss
    raise TrainingError(f"config key 'surrogate.loss' must be 'mae' or 'mse', got {name!r}")


def _jacobian_data(ds: xr.Dataset, net, device) -> dict[str, torch.Tensor]:
    """Per training sample: trial strain, converged strain and Δε_acc of the previous step, and the
    reference tangent as the Jacobian of the SCALED stress wrt the SCALED strain."""
    strain = ds["strain"].transpose("step", "gp", "comp").values
    acc = accumulated_from_sequence(strain)
    strain_c = np.concatenate([strain[:1], strain[:-1]])
    acc_c = np.concatenate([acc[:1], acc[:-1]])
    # D acts on engineering strain; ∂σ/∂ε (tensorial) = D · diag(1, 1, 1, 2, 2, 2)
    jac = tangent_from_upper(ds["tangent"].transpose("step", "gp", "tcomp").values) * ENGINEERING_FACTOR
    x_scale = net.x_scale[:6].detach().cpu().double().numpy()
    y_scale = net.y_scale.detach().cpu().double().numpy()
    jac_scaled = jac * x_scale[None, None, None, :] / y_scale[None, None, :, None]
    # directions only along strains that vary in the data (a roundoff-constant column has scale 1)
    varies = (net.x_max[:6] - net.x_min[:6] > 0) & (net.x_scale[:6] != 1.0)
    flat = lambda a: torch.as_tensor(a.reshape(-1, *a.shape[2:]), dtype=torch.float32, device=device)  # noqa: E731
    return {"strain": flat(strain), "strain_c": flat(strain_c), "acc_c": flat(acc_c), "target": flat(jac_scaled),
            "mask": varies.to(device=device, dtype=torch.float32), "x_scale": net.x_scale[:6].detach()}


def _directional_slopes(net, jac: dict, idx, history, generator):
    """Scaled stress at the samples, and its derivative along one random scaled-strain direction per
    sample (forward mode, one pass) next to the reference tangent's: a stochastic Jacobian loss."""
    v = torch.randn(len(idx), 6, generator=generator).to(jac["mask"].device) * jac["mask"]
    v = v / v.norm(dim=1, keepdim=True).clamp_min(1e-12)
    acc_c, strain_c = jac["acc_c"][idx], jac["strain_c"][idx]

    def scaled_stress(strain):
        return net.forward_scaled(net.scale_x(trial_features(strain, acc_c, strain_c, history)))

    prediction, slope = jvp(scaled_stress, (jac["strain"][idx],), (v * jac["x_scale"],))
    return prediction, slope, torch.einsum("bij,bj->bi", jac["target"][idx], v)


def _scheduler(optimiser, settings: dict, epochs: int):
    """Learning-rate schedule per epoch: constant (the paper) or cosine decay to final_learning_rate."""
    kind = settings.get("lr_schedule", "constant")
    if kind == "constant":
        return None
    if kind == "cosine":
        final = float(settings.get("final_learning_rate", 0.0))
        return torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, T_max=max(epochs, 1), eta_min=final)
    raise TrainingError(f"config key 'surrogate.lr_schedule' must be 'constant' or 'cosine', got {kind!r}")


def train(
    train_ds: xr.Dataset,
    heldout_ds: xr.Dataset,
    kind: str,
    settings: dict,
    seed: int,
    use_history: bool = True,
    config: dict | None = None,
    logger: logging.Logger | None = None,
) -> tuple[SurrogateModel, pd.DataFrame, pd.DataFrame]:
    """Train NNσ (kind 'sigma') or ND (kind 'tangent'). Returns (model, loss per epoch, MAE table)."""
    logger = logger or logging.getLogger(__name__)
    target_names(kind)
    torch.set_num_threads(int(settings.get("torch_threads", 1)))
    torch.use_deterministic_algorithms(True)
    device = _device(settings)
    loss_fn = _loss_fn(settings["loss"])
    epochs, batch_size = int(settings["epochs"]), int(settings["batch_size"])
    log_every = int(settings.get("log_every", 50))
    rng_seed = model_seed(seed, kind, use_history)
    history = history_selection(settings.get("history_variables", True)) if use_history else ()

    torch.manual_seed(rng_seed)
    model = SurrogateModel.create(kind, history, scaling(train_ds, kind, history), settings, config)
    net = model.network.to(device)
    as_t = lambda a: torch.as_tensor(a, dtype=torch.float32, device=device)  # noqa: E731
    with torch.no_grad():
        x_tr = net.scale_x(as_t(features(train_ds, history)))
        y_tr = net.scale_y(as_t(targets(train_ds, kind)))
        x_ho = net.scale_x(as_t(features(heldout_ds, history)))
        y_ho = net.scale_y(as_t(targets(heldout_ds, kind)))
    n = x_tr.shape[0]
    jacobian_weight = float(settings.get("jacobian_loss_weight", 0.0)) if kind == "sigma" else 0.0
    jac = _jacobian_data(train_ds, net, device) if jacobian_weight > 0 else None
    optimiser = torch.optim.Adam(net.parameters(), lr=float(settings["learning_rate"]))
    scheduler = _scheduler(optimiser, settings, epochs)
    generator = torch.Generator().manual_seed(rng_seed)
    name = f"{'NNσ' if kind == 'sigma' else 'ND'}{'' if use_history else ' (no history)'}"
    logger.info(
        "%s: %d -> %d, %d train / %d held-out samples, %d epochs, batch %d, lr %g (%s), %s loss%s, seed %d",
        name, x_tr.shape[1], y_tr.shape[1], n, x_ho.shape[0], epochs, batch_size,
        settings["learning_rate"], settings.get("lr_schedule", "constant"), settings["loss"],
        f" + {jacobian_weight:g} × Jacobian loss" if jac is not None else "", rng_seed,
    )

    rows = []
    t0 = time.perf_counter()
    for epoch in range(1, epochs + 1):
        net.train()
        order = torch.randperm(n, generator=generator).to(device)
        for start in range(0, n, batch_size):
            idx = order[start : start + batch_size]
            if jac is None:
                loss = loss_fn(net.forward_scaled(x_tr[idx]), y_tr[idx])
            else:
                prediction, slope, target_slope = _directional_slopes(net, jac, idx, history, generator)
                loss = loss_fn(prediction, y_tr[idx]) + jacobian_weight * loss_fn(slope, target_slope)
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            optimiser.step()
        if scheduler is not None:
            scheduler.step()
        net.eval()
        with torch.no_grad():
            train_loss = float(loss_fn(net.forward_scaled(x_tr), y_tr))
            heldout_loss = float(loss_fn(net.forward_scaled(x_ho), y_ho))
        if not (np.isfinite(train_loss) and np.isfinite(heldout_loss)):
            raise TrainingError(f"{name}: loss is not finite at epoch {epoch}; lower surrogate.learning_rate")
        rows.append((epoch, train_loss, heldout_loss, time.perf_counter() - t0))
        if epoch % log_every == 0 or epoch == epochs:
            logger.info("%s epoch %d/%d: train %.3e, held-out %.3e (%.1f s)", name, epoch, epochs, train_loss, heldout_loss, rows[-1][3])

    net = net.cpu()
    model.network = net
    losses = pd.DataFrame(rows, columns=["epoch", "train_loss", "heldout_loss", "elapsed_s"])
    mae = component_mae(model, train_ds, heldout_ds)
    model.initial_state = initial_state(train_ds, kind, history)
    model.training = {
        "seed": rng_seed,
        "epochs": epochs,
        "final_train_loss": rows[-1][1],
        "final_heldout_loss": rows[-1][2],
        "train_gp": np.asarray(train_ds.gp.values).tolist(),
        "heldout_gp": np.asarray(heldout_ds.gp.values).tolist(),
        "wall_time_s": rows[-1][3],
        "torch_version": torch.__version__,
    }
    return model, losses, mae


def initial_state(ds: xr.Dataset, kind: str, history=True) -> dict:
    """Mean features and targets of step 0 (the fresh, consolidated state) over the dataset's points."""
    fresh = ds.isel(step=[0])
    return {
        "features": features(fresh, history).mean(axis=0).tolist(),
        "targets": targets(fresh, kind).mean(axis=0).tolist(),
    }


def component_mae(model: SurrogateModel, train_ds: xr.Dataset, heldout_ds: xr.Dataset) -> pd.DataFrame:
    """MAE of every target in physical units (Pa) on the train and held-out points, and relative to its range."""
    out = {}
    for split, ds in (("train", train_ds), ("heldout", heldout_ds)):
        y = targets(ds, model.kind)
        pred = model.predict(features(ds, model.history))
        out[split] = np.mean(np.abs(pred - y), axis=0)
    net = model.network
    span = (net.y_max - net.y_min).detach().cpu().double().numpy()
    table = pd.DataFrame(
        {
            "target": list(model.target_names),
            "train_mae_pa": out["train"],
            "heldout_mae_pa": out["heldout"],
            "train_range_pa": span,
        }
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        table["heldout_mae_percent_of_range"] = np.where(span > 0, 100 * out["heldout"] / np.where(span > 0, span, 1), np.nan)
    return table


def plot_losses(losses: dict[str, pd.DataFrame], path, loss_name: str = "MAE") -> None:
    """Training and held-out loss per epoch of one or more networks, log scale."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for (label, df), colour in zip(losses.items(), plt.rcParams["axes.prop_cycle"].by_key()["color"]):
        ax.semilogy(df["epoch"], df["train_loss"], color=colour, label=f"{label} train")
        ax.semilogy(df["epoch"], df["heldout_loss"], color=colour, linestyle="--", label=f"{label} held-out")
    ax.set_xlabel("epoch")
    ax.set_ylabel(f"{loss_name} (scaled targets)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=120, format="png")
    finally:
        plt.close(fig)


def write_table(table: pd.DataFrame, path) -> None:
    """CSV written atomically (temporary file in the target folder, then rename)."""
    with atomic_path(path) as tmp:
        table.to_csv(tmp, index=False)
