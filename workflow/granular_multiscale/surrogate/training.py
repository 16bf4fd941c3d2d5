"""Training of NNσ and ND: seeded, deterministic on the CPU, every hyperparameter from the config.

Adam on the min–max scaled data (MAE loss by default, paper Table 3), mini-batches drawn
by a seeded generator; the held-out Gauss points give the validation loss of every epoch
but never choose anything (the final weights are those of the last epoch). With
``surrogate.ensemble_size`` K > 1 this is done K times from different seeds (the K fits stacked
into one batched fit, which makes the same updates) and the model is the members' mean. Outputs:

* the :class:`~.models.SurrogateModel` (weights, scaling, names, config, training summary),
* the loss history per epoch and member (train and held-out, on the scaled targets),
* the final MAE of every target component in physical units on the train and held-out points.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np
import pandas as pd
import torch
import xarray as xr

from torch.func import jvp

from ..atomic import atomic_path
from ..history import accumulated_from_sequence, peak_from_sequence
from ..novelty import TrainingStates, sample_states
from ..tensors import ENGINEERING_FACTOR, tangent_from_upper, tensor_norm
from .dataset import (consolidation_pressures, features, history_selection, sample_mask, sample_trajectories, scaling,
                      strain_history, takes_pressure, target_names, targets)
from .models import EnsembleMLP, ScaledMLP, SurrogateModel, trial_features

_KIND_INDEX = {"sigma": 0, "tangent": 1}
#: training inputs a model file keeps for the material's distance to the training data: enough
#: for a 5-nearest-neighbour radius, small beside the weights (20 000 × 11 float64 = 1.8 MB)
TRAINING_STATES_KEPT = 20_000
#: surrogate.ensemble_resampling: each member on all the data (none) or on its own bootstrap
#: sample of the training trajectories
RESAMPLING = ("none", "trajectories")


class TrainingError(RuntimeError):
    """Training cannot run or diverged; the message names the config key or the epoch."""


def model_seed(seed: int, kind: str, use_history: bool, member: int = 0) -> int:
    """Distinct, reproducible seed per network (NNσ, ND, with and without history) and ensemble
    member; member 0 has the seed a single network has."""
    key = [int(seed), _KIND_INDEX[kind], int(bool(use_history))] + ([int(member)] if member else [])
    return int(np.random.SeedSequence(key).generate_state(1)[0])


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
    """Per training sample: trial strain, converged strain, Δε_acc and running maxima ψ of the previous step, and the
    reference tangent as the Jacobian of the SCALED stress wrt the SCALED strain."""
    strain = ds["strain"].transpose("step", "gp", "comp").values
    previous = lambda a: np.concatenate([a[:1], a[:-1]])  # noqa: E731  (step 0 is its own predecessor)
    strain_c, acc_c, peak_c = previous(strain), previous(accumulated_from_sequence(strain)), previous(peak_from_sequence(strain))
    # D acts on engineering strain; ∂σ/∂ε (tensorial) = D · diag(1, 1, 1, 2, 2, 2)
    jac = tangent_from_upper(ds["tangent"].transpose("step", "gp", "tcomp").values) * ENGINEERING_FACTOR
    x_scale = net.x_scale[:6].detach().cpu().double().numpy()
    y_scale = net.y_scale.detach().cpu().double().numpy()
    jac_scaled = jac * x_scale[None, None, None, :] / y_scale[None, None, :, None]
    # directions only along strains that vary in the data (a roundoff-constant column has scale 1)
    varies = (net.x_max[:6] - net.x_min[:6] > 0) & (net.x_scale[:6] != 1.0)
    keep = sample_mask(ds)  # padding and lost-contact entries are no samples
    flat = lambda a: torch.as_tensor(a.reshape(-1, *a.shape[2:])[keep], dtype=torch.float32, device=device)  # noqa: E731
    # p0 per sample, read only by networks that take it (features() has checked it is known then)
    pressure = ds["consolidation_pressure"].values if "consolidation_pressure" in ds else np.full(ds.sizes["gp"], np.nan)
    return {"strain": flat(strain), "strain_c": flat(strain_c), "acc_c": flat(acc_c), "peak_c": flat(peak_c),
            "pressure": flat(np.broadcast_to(pressure, strain.shape[:2]).copy()), "target": flat(jac_scaled),
            "mask": varies.to(device=device, dtype=torch.float32), "x_scale": net.x_scale[:6].detach()}


def _directional_slopes(net, jac: dict, idx, history, generator):
    """Scaled stress at the samples, and its derivative along one random scaled-strain direction per
    sample (forward mode, one pass) next to the reference tangent's: a stochastic Jacobian loss."""
    v = torch.randn(len(idx), 6, generator=generator).to(jac["mask"].device) * jac["mask"]
    v = v / v.norm(dim=1, keepdim=True).clamp_min(1e-12)
    acc_c, strain_c, peak_c = jac["acc_c"][idx], jac["strain_c"][idx], jac["peak_c"][idx]

    def scaled_stress(strain):
        return net.forward_scaled(net.scale_x(trial_features(strain, acc_c, strain_c, peak_c, history,
                                                             jac["pressure"][idx])))

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


@dataclass
class _Fit:
    """What every network of one training shares: scaled data, loss, options."""

    x_tr: torch.Tensor
    y_tr: torch.Tensor
    x_ho: torch.Tensor
    y_ho: torch.Tensor
    loss_fn: object
    history: tuple
    jac: dict | None
    jacobian_weight: float
    epochs: int
    batch_size: int
    log_every: int


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
    """Train NNσ (kind 'sigma') or ND (kind 'tangent'). Returns (model, loss per epoch, MAE table).

    With ``surrogate.ensemble_size`` K > 1 it trains K networks from seeds model_seed(..., member)
    and the model is their mean (models.EnsembleMLP); the loss table has one block per member."""
    logger = logger or logging.getLogger(__name__)
    target_names(kind)
    torch.set_num_threads(int(settings.get("torch_threads", 1)))
    torch.use_deterministic_algorithms(True)
    device = _device(settings)
    n_members = int(settings.get("ensemble_size", 1))
    if n_members < 1:
        raise TrainingError(f"config key 'surrogate.ensemble_size' must be >= 1, got {n_members}")
    history = history_selection(settings.get("history_variables", True)) if use_history else ()
    seeds = [model_seed(seed, kind, use_history, member) for member in range(n_members)]
    resampling = settings.get("ensemble_resampling", "none")
    if resampling not in RESAMPLING:
        raise TrainingError(f"config key 'surrogate.ensemble_resampling' must be one of {RESAMPLING}, got {resampling!r}")
    trajectories = sample_trajectories(train_ds) if resampling == "trajectories" else None

    torch.manual_seed(seeds[0])
    model = SurrogateModel.create(kind, history, scaling(train_ds, kind, history), settings, config)
    first = model.network.to(device)
    as_t = lambda a: torch.as_tensor(a, dtype=torch.float32, device=device)  # noqa: E731
    with torch.no_grad():
        x_tr, y_tr = first.scale_x(as_t(features(train_ds, history))), first.scale_y(as_t(targets(train_ds, kind)))
        x_ho, y_ho = first.scale_x(as_t(features(heldout_ds, history))), first.scale_y(as_t(targets(heldout_ds, kind)))
    jacobian_weight = float(settings.get("jacobian_loss_weight", 0.0)) if kind == "sigma" else 0.0
    fit = _Fit(x_tr, y_tr, x_ho, y_ho, _loss_fn(settings["loss"]), history,
               _jacobian_data(train_ds, first, device) if jacobian_weight > 0 else None, jacobian_weight,
               int(settings["epochs"]), int(settings["batch_size"]), int(settings.get("log_every", 50)))
    name = f"{'NNσ' if kind == 'sigma' else 'ND'}{'' if use_history else ' (no history)'}"
    logger.info(
        "%s: %d -> %d, %d train / %d held-out samples, %d epochs, batch %d, lr %g (%s), %s loss%s, %s",
        name, x_tr.shape[1], y_tr.shape[1], x_tr.shape[0], x_ho.shape[0], fit.epochs, fit.batch_size,
        settings["learning_rate"], settings.get("lr_schedule", "constant"), settings["loss"],
        f" + {jacobian_weight:g} × Jacobian loss" if fit.jac is not None else "",
        f"seed {seeds[0]}" if n_members == 1 else f"ensemble of {n_members}, seeds {seeds}",
    )

    nets = [first]  # initialised above from seeds[0]; each other member from its own seed
    for member_seed in seeds[1:]:
        torch.manual_seed(member_seed)
        nets.append(ScaledMLP(**model.architecture, **first.exact_scaling).to(device))
    labels = [name] if n_members == 1 else [f"{name} member {m + 1}/{n_members}" for m in range(n_members)]
    started = time.perf_counter()
    if n_members > 1 and fit.jac is None and trajectories is None:
        # the same fits as one after the other (same initial weights, batches and Adam updates),
        # stacked into batched matrix products: twice as fast for the default ensemble of 3
        member_rows = _fit_together(nets, fit, settings, seeds, labels, logger)
    else:
        member_rows = [_fit_network(net, fit, settings, member_seed, label, logger,
                                    None if trajectories is None else bootstrap_rows(trajectories, member_seed))
                       for net, member_seed, label in zip(nets, seeds, labels)]
    wall_time = time.perf_counter() - started
    members = [net.cpu() for net in nets]
    losses = [pd.DataFrame(rows, columns=["epoch", "train_loss", "heldout_loss", "elapsed_s"]).assign(member=member)
              for member, rows in enumerate(member_rows)]

    model.network = members[0] if n_members == 1 else EnsembleMLP(members)
    model.network.eval()
    with torch.no_grad():  # the loss of what is used: the ensemble mean (for one network, its last epoch)
        final_train, final_heldout = (float(fit.loss_fn(model.network.forward_scaled(x.cpu()), y.cpu()))
                                      for x, y in ((x_tr, y_tr), (x_ho, y_ho)))
    mae = component_mae(model, train_ds, heldout_ds)
    model.initial_state = initial_state(train_ds, kind, history)
    model.training_states = sample_states(features(train_ds, history), TRAINING_STATES_KEPT, seeds[0])
    model.training_radius = TrainingStates(model.training_states).radius
    model.training = {
        "seed": seeds[0],
        "member_seeds": seeds,
        "ensemble_resampling": resampling,
        "epochs": fit.epochs,
        "final_train_loss": final_train,
        "final_heldout_loss": final_heldout,
        "train_gp": np.asarray(train_ds.gp.values).tolist(),
        "heldout_gp": np.asarray(heldout_ds.gp.values).tolist(),
        "wall_time_s": wall_time,
        "torch_version": torch.__version__,
        # the pressure the training RVEs were consolidated at (None: the dataset's sources record none,
        # or differ); FEM–ML compares it with the specimen's (surrogate.other_pressure)
        "confining_pressure_Pa": (float(train_ds.attrs["confining_pressure_Pa"])
                                  if "confining_pressure_Pa" in train_ds.attrs else None),
    }
    return model, pd.concat(losses, ignore_index=True), mae


def bootstrap_rows(trajectories: np.ndarray, seed: int) -> np.ndarray:
    """The training rows of one bootstrap sample of trajectories: as many trajectories as there are,
    drawn with replacement (seeded), each drawn one contributing all its samples once per draw.
    Members fitted to different samples disagree where the data are thin (a trajectory's
    neighbourhood that one member never saw), not only where their seeds lead them apart."""
    ids = np.unique(trajectories)
    drawn = np.random.default_rng(seed).choice(ids, size=ids.size, replace=True)
    counts = np.bincount(np.searchsorted(ids, drawn), minlength=ids.size)
    per_row = counts[np.searchsorted(ids, trajectories)]
    return np.repeat(np.arange(trajectories.size), per_row)


def _fit_network(net, fit: _Fit, settings: dict, rng_seed: int, name: str, logger: logging.Logger,
                 member_rows: np.ndarray | None = None) -> list[tuple]:
    """Adam over mini-batches from a generator seeded with rng_seed; rows (epoch, train loss, held-out loss, s).
    `member_rows`: the training rows this network is fitted to (a bootstrap sample, rows repeated);
    all of them by default. The train loss is reported over all training rows either way."""
    optimiser = torch.optim.Adam(net.parameters(), lr=float(settings["learning_rate"]))
    scheduler = _scheduler(optimiser, settings, fit.epochs)
    generator = torch.Generator().manual_seed(rng_seed)
    pool = (torch.arange(fit.x_tr.shape[0]) if member_rows is None else torch.as_tensor(member_rows)).to(fit.x_tr.device)
    n = pool.shape[0]
    rows = []
    t0 = time.perf_counter()
    for epoch in range(1, fit.epochs + 1):
        net.train()
        order = pool[torch.randperm(n, generator=generator).to(fit.x_tr.device)]
        for start in range(0, n, fit.batch_size):
            idx = order[start : start + fit.batch_size]
            if fit.jac is None:
                loss = fit.loss_fn(net.forward_scaled(fit.x_tr[idx]), fit.y_tr[idx])
            else:
                prediction, slope, target_slope = _directional_slopes(net, fit.jac, idx, fit.history, generator)
                loss = fit.loss_fn(prediction, fit.y_tr[idx]) + fit.jacobian_weight * fit.loss_fn(slope, target_slope)
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            optimiser.step()
        if scheduler is not None:
            scheduler.step()
        net.eval()
        with torch.no_grad():
            train_loss = float(fit.loss_fn(net.forward_scaled(fit.x_tr), fit.y_tr))
            heldout_loss = float(fit.loss_fn(net.forward_scaled(fit.x_ho), fit.y_ho))
        if not (np.isfinite(train_loss) and np.isfinite(heldout_loss)):
            raise TrainingError(f"{name}: loss is not finite at epoch {epoch}; lower surrogate.learning_rate")
        rows.append((epoch, train_loss, heldout_loss, time.perf_counter() - t0))
        if epoch % fit.log_every == 0 or epoch == fit.epochs:
            logger.info("%s epoch %d/%d: train %.3e, held-out %.3e (%.1f s)", name, epoch, fit.epochs, train_loss, heldout_loss, rows[-1][3])
    return rows


def _fit_together(nets: list, fit: _Fit, settings: dict, seeds: list[int], labels: list[str],
                  logger: logging.Logger) -> list[list[tuple]]:
    """_fit_network for every member at once, on all the training rows; the members' weights are
    stacked ([members, in, out] per layer) for the fit and written back into `nets` after it.

    Each member draws its batches from its own generator seeded as in _fit_network, and Adam's
    update is elementwise, so the stacked fit makes the same updates as fitting the members one
    after the other (up to the rounding of batched matrix products). The loss summed over the
    members has each member's loss as its gradient with respect to that member's weights."""
    linears = [[layer for layer in net.net if isinstance(layer, torch.nn.Linear)] for net in nets]
    activation = next((layer for layer in nets[0].net if not isinstance(layer, torch.nn.Linear)), None)
    weights = [torch.nn.Parameter(torch.stack([member[k].weight.detach().T for member in linears]).contiguous())
               for k in range(len(linears[0]))]
    biases = [torch.nn.Parameter(torch.stack([member[k].bias.detach()[None, :] for member in linears]).contiguous())
              for k in range(len(linears[0]))]
    optimiser = torch.optim.Adam([p for pair in zip(weights, biases) for p in pair], lr=float(settings["learning_rate"]))
    scheduler = _scheduler(optimiser, settings, fit.epochs)
    generators = [torch.Generator().manual_seed(seed) for seed in seeds]
    n_members, n = len(nets), fit.x_tr.shape[0]

    def forward(x):  # x [members, rows, in] -> [members, rows, out]
        for k, (w, b) in enumerate(zip(weights, biases)):
            x = torch.baddbmm(b, x, w)
            if k < len(weights) - 1:
                x = activation(x)
        return x

    def member_losses(x, y):  # per member, as fit.loss_fn over its own rows
        prediction = forward(x)
        return torch.stack([fit.loss_fn(prediction[m], y[m]) for m in range(n_members)])

    rows: list[list[tuple]] = [[] for _ in nets]
    t0 = time.perf_counter()
    for epoch in range(1, fit.epochs + 1):
        orders = torch.stack([torch.randperm(n, generator=g).to(fit.x_tr.device) for g in generators])
        for start in range(0, n, fit.batch_size):
            idx = orders[:, start : start + fit.batch_size]
            loss = member_losses(fit.x_tr[idx], fit.y_tr[idx]).sum()
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            optimiser.step()
        if scheduler is not None:
            scheduler.step()
        with torch.no_grad():
            train = member_losses(fit.x_tr.expand(n_members, -1, -1), fit.y_tr.expand(n_members, -1, -1))
            heldout = member_losses(fit.x_ho.expand(n_members, -1, -1), fit.y_ho.expand(n_members, -1, -1))
        elapsed = time.perf_counter() - t0
        for m, label in enumerate(labels):
            train_loss, heldout_loss = float(train[m]), float(heldout[m])
            if not (np.isfinite(train_loss) and np.isfinite(heldout_loss)):
                raise TrainingError(f"{label}: loss is not finite at epoch {epoch}; lower surrogate.learning_rate")
            rows[m].append((epoch, train_loss, heldout_loss, elapsed))
            if epoch % fit.log_every == 0 or epoch == fit.epochs:
                logger.info("%s epoch %d/%d: train %.3e, held-out %.3e (%.1f s)", label, epoch, fit.epochs,
                            train_loss, heldout_loss, elapsed)
    with torch.no_grad():
        for m, member in enumerate(linears):
            for k, layer in enumerate(member):
                layer.weight.copy_(weights[k][m].T)
                layer.bias.copy_(biases[k][m, 0])
    return rows


def initial_state(ds: xr.Dataset, kind: str, history=True) -> dict:
    """Mean features and targets of step 0 (the fresh, consolidated state) over the dataset's points;
    with p0 among the features, also per consolidation pressure (``by_pressure``, sorted by p0)."""
    fresh = ds.isel(step=[0])
    state = {
        "features": features(fresh, history).mean(axis=0).tolist(),
        "targets": targets(fresh, kind).mean(axis=0).tolist(),
    }
    if takes_pressure(history):
        pressures = consolidation_pressures(fresh)
        state["by_pressure"] = [
            {"pressure": float(p), **initial_state(fresh.isel(gp=np.flatnonzero(pressures == p)), kind, strain_history(history))}
            for p in np.unique(pressures)]
        for entry in state["by_pressure"]:  # the features at that pressure: p0 appended
            entry["features"] = [*entry["features"], entry["pressure"]]
    return state


def heldout_spread_scale(model: SurrogateModel, heldout: xr.Dataset) -> dict:
    """The ensemble spread's scale on the held-out trajectories of the networks' dataset: the median over
    their (step ≥ 1) samples of ‖σ_NN − σ_ref‖ / ‖spread‖ (tensor norms, shear counted twice), each
    member anchored as FEM–ML anchors it, fed the trajectory's recorded strain and history (no FEM).
    Members trained on the same data share much of their error; this says by how much their spread
    understates it, on data independent of any run it is then applied to (``analysis.calibration``).
    Returns scale, pairs (samples with a positive spread), trajectories and the 10th and 90th
    percentiles of the ratio; the scale is NaN for one network (no spread)."""
    steps = np.broadcast_to(heldout["step"].values[:, None], (heldout.sizes["step"], heldout.sizes["gp"]))
    later = steps.reshape(-1)[sample_mask(heldout)] >= 1  # step 0: the anchored fresh state, exact
    x, y = features(heldout, model.history)[later], targets(heldout, "sigma")[later]
    members = model.predict_members(x) + model.initial_offset(per_member=True)[:, None, :]
    error, spread = tensor_norm(members.mean(axis=0) - y), tensor_norm(members.std(axis=0))
    positive = spread > 0
    ratio = error[positive] / spread[positive]
    nan = float("nan")
    return {"scale": float(np.median(ratio)) if ratio.size else nan, "pairs": int(positive.sum()),
            "trajectories": int(np.unique(sample_trajectories(heldout)[later]).size),
            "p10_error_over_spread": float(np.percentile(ratio, 10)) if ratio.size else nan,
            "p90_error_over_spread": float(np.percentile(ratio, 90)) if ratio.size else nan}


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


def write_table(table: pd.DataFrame, path) -> None:
    """CSV written atomically (temporary file in the target folder, then rename)."""
    with atomic_path(path) as tmp:
        table.to_csv(tmp, index=False)
