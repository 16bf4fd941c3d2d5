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

from .dataset import features, scaling, target_names, targets
from .models import SurrogateModel

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

    torch.manual_seed(rng_seed)
    model = SurrogateModel.create(kind, use_history, scaling(train_ds, kind, use_history), settings, config)
    net = model.network.to(device)
    as_t = lambda a: torch.as_tensor(a, dtype=torch.float32, device=device)  # noqa: E731
    with torch.no_grad():
        x_tr = net.scale_x(as_t(features(train_ds, use_history)))
        y_tr = net.scale_y(as_t(targets(train_ds, kind)))
        x_ho = net.scale_x(as_t(features(heldout_ds, use_history)))
        y_ho = net.scale_y(as_t(targets(heldout_ds, kind)))
    n = x_tr.shape[0]
    optimiser = torch.optim.Adam(net.parameters(), lr=float(settings["learning_rate"]))
    generator = torch.Generator().manual_seed(rng_seed)
    name = f"{'NNσ' if kind == 'sigma' else 'ND'}{'' if use_history else ' (no history)'}"
    logger.info(
        "%s: %d -> %d, %d train / %d held-out samples, %d epochs, batch %d, lr %g, %s loss, seed %d",
        name, x_tr.shape[1], y_tr.shape[1], n, x_ho.shape[0], epochs, batch_size,
        settings["learning_rate"], settings["loss"], rng_seed,
    )

    rows = []
    t0 = time.perf_counter()
    for epoch in range(1, epochs + 1):
        net.train()
        order = torch.randperm(n, generator=generator).to(device)
        for start in range(0, n, batch_size):
            idx = order[start : start + batch_size]
            loss = loss_fn(net.forward_scaled(x_tr[idx]), y_tr[idx])
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            optimiser.step()
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


def component_mae(model: SurrogateModel, train_ds: xr.Dataset, heldout_ds: xr.Dataset) -> pd.DataFrame:
    """MAE of every target in physical units (Pa) on the train and held-out points, and relative to its range."""
    out = {}
    for split, ds in (("train", train_ds), ("heldout", heldout_ds)):
        y = targets(ds, model.kind)
        pred = model.predict(features(ds, model.use_history))
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
    fig.savefig(path, dpi=120)
    plt.close(fig)
