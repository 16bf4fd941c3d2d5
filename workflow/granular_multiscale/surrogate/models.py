"""The surrogate networks NNσ (features -> 6 stresses) and ND (features -> 21 tangent entries).

A :class:`ScaledMLP` is a plain MLP (paper Table 3: 4 hidden layers × 20 units) wrapped by
its min–max scaling, kept as buffers: ``forward`` takes features and returns targets in
physical units (Pa), so it can be differentiated end to end (autodiff tangent).

An :class:`EnsembleMLP` (config ``surrogate.ensemble_size`` > 1) is the mean of K such networks
trained from different seeds on the same data; it is used exactly like one.

A :class:`SurrogateModel` adds what makes the saved file self-sufficient: which targets it
predicts, the feature and target names, the scaling, the config and the training summary.
``SurrogateModel.load(path)`` needs nothing else.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import nn

from .. import integrity
from ..atomic import atomic_path
from ..history import HIST, trial_history_torch
from .dataset import (HISTORY_FEATURES, STRAIN_FEATURES, feature_names, strain_history, takes_pressure,
                      target_names)

FORMAT = "granular_multiscale.surrogate/2"
# format 1 held one network's weights under "state_dict"; format 2 a list under "members"
READABLE_FORMATS = ("granular_multiscale.surrogate/1", FORMAT)
ACTIVATIONS = {
    "tanh": nn.Tanh,
    "relu": nn.ReLU,
    "gelu": nn.GELU,
    "silu": nn.SiLU,
    "softplus": nn.Softplus,
    "elu": nn.ELU,
    "sigmoid": nn.Sigmoid,
}


def trial_features(strain: torch.Tensor, acc_c: torch.Tensor, strain_c: torch.Tensor, peak_c: torch.Tensor,
                   history=True, pressure: torch.Tensor | None = None) -> torch.Tensor:
    """[..., 6] trial strain with the converged strain, Δε_acc and running maxima (ψ1, ψ2) of the
    last step -> network features.

    Δε_acc = Δε_acc,c + |ε − ε_c|, φ = φ(Δε_acc), ψ = max(ψ_c, ‖ε‖) (history module): differentiable
    in the trial strain, so the autodiff tangent and the Jacobian loss both see the chain rule
    through the history variables. `history` selects them (see dataset.history_selection);
    `pressure` [...] is p0 of each point (Pa), needed when the selection holds p0."""
    chosen = strain_history(history)
    parts = [strain]
    if chosen:
        values = trial_history_torch(strain, acc_c, strain_c, peak_c)
        parts.append(values if chosen == HIST else values[..., [HIST.index(h) for h in chosen]])
    if takes_pressure(history):
        if pressure is None:
            raise ValueError("the networks take p0, the consolidation pressure: give it (Pa) per point")
        parts.append(torch.broadcast_to(torch.as_tensor(pressure, dtype=strain.dtype), strain.shape[:-1])[..., None])
    return torch.cat(parts, dim=-1) if len(parts) > 1 else strain


def fresh_state_at(by_pressure: list[dict], pressure: float) -> dict:
    """{features, targets} of the fresh state at `pressure`: linear in p0 between the recorded
    pressures (``{pressure, features, targets}`` each), extrapolated from the nearest two beyond."""
    states = sorted(by_pressure, key=lambda state: state["pressure"])
    if len(states) == 1:
        return states[0]
    known = np.array([state["pressure"] for state in states])
    upper = int(np.clip(np.searchsorted(known, pressure), 1, known.size - 1))
    weight = (pressure - known[upper - 1]) / (known[upper] - known[upper - 1])
    return {key: ((1.0 - weight) * np.asarray(states[upper - 1][key], dtype=float)
                  + weight * np.asarray(states[upper][key], dtype=float)).tolist() for key in ("features", "targets")}


class ModelFileError(ValueError):
    """A model file is missing, unreadable or not a surrogate model; the message names the file."""


# A span below this fraction of the largest span of its unit group is roundoff, not data.
NEGLIGIBLE_SPAN = 1e-9


def scale_of(lo, hi, groups) -> np.ndarray:
    """Divisor of the min–max scaling per column: max − min, or 1 for a constant column.

    A column is constant when its span is below NEGLIGIBLE_SPAN times the largest span of
    the columns it shares units with (`groups`: one id per column). On a symmetric mesh a
    shear strain or stress can be zero up to roundoff (1e-20) at every training point:
    dividing by that span would turn the next roundoff-sized input into an O(1) feature."""
    lo, hi, groups = np.asarray(lo, float), np.asarray(hi, float), np.asarray(groups)
    span = hi - lo
    scale = np.ones_like(span)
    for g in np.unique(groups):
        pick = groups == g
        largest = span[pick].max(initial=0.0)
        real = pick & (span > NEGLIGIBLE_SPAN * largest) & (span > 0)
        scale[real] = span[real]
    return scale


def column_groups(n_columns: int, n_shared: int) -> np.ndarray:
    """The first n_shared columns share units (strains, stresses, tangent entries); each other is its own."""
    return np.concatenate([np.zeros(min(n_shared, n_columns), int), np.arange(1, 1 + max(n_columns - n_shared, 0))])


def activation_derivative(layer: nn.Module, z: torch.Tensor) -> torch.Tensor:
    """Elementwise derivative of an activation layer at its input z."""
    if isinstance(layer, nn.Tanh):
        return 1.0 - torch.tanh(z) ** 2
    if isinstance(layer, nn.ReLU):
        return (z > 0).to(z.dtype)
    if isinstance(layer, nn.GELU):  # exact (erf) GELU: Φ(z) + z φ(z)
        return 0.5 * (1.0 + torch.erf(z / np.sqrt(2.0))) + z * torch.exp(-0.5 * z * z) / np.sqrt(2.0 * np.pi)
    if isinstance(layer, nn.SiLU):
        s = torch.sigmoid(z)
        return s * (1.0 + z * (1.0 - s))
    if isinstance(layer, nn.Softplus):
        return torch.sigmoid(layer.beta * z) * (layer.beta * z <= layer.threshold) + (layer.beta * z > layer.threshold)
    if isinstance(layer, nn.ELU):
        return torch.where(z > 0, torch.ones_like(z), layer.alpha * torch.exp(z))
    if isinstance(layer, nn.Sigmoid):
        s = torch.sigmoid(z)
        return s * (1.0 - s)
    raise TypeError(f"no derivative for activation {type(layer).__name__}")


class ScaledMLP(nn.Module):
    def __init__(self, n_in: int, n_out: int, hidden_layers: int, hidden_units: int, activation: str,
                 x_min, x_max, y_min, y_max):
        super().__init__()
        if activation not in ACTIVATIONS:
            raise ValueError(f"surrogate.activation must be one of {sorted(ACTIVATIONS)}, got {activation!r}")
        layers: list[nn.Module] = []
        width = n_in
        for _ in range(hidden_layers):
            layers += [nn.Linear(width, hidden_units), ACTIVATIONS[activation]()]
            width = hidden_units
        layers.append(nn.Linear(width, n_out))
        self.net = nn.Sequential(*layers)
        # the exact (float64) scaling is what the model file stores, whatever dtype the weights train in
        self.exact_scaling = {k: np.asarray(v, dtype=np.float64).copy() for k, v in
                              (("x_min", x_min), ("x_max", x_max), ("y_min", y_min), ("y_max", y_max))}
        as_t = lambda v: torch.as_tensor(np.asarray(v, dtype=np.float64), dtype=torch.float32)  # noqa: E731
        self.register_buffer("x_min", as_t(x_min))
        self.register_buffer("x_max", as_t(x_max))
        self.register_buffer("y_min", as_t(y_min))
        self.register_buffer("y_max", as_t(y_max))
        if self.x_min.shape != (n_in,) or self.y_min.shape != (n_out,):
            raise ValueError(f"scaling shapes {tuple(self.x_min.shape)}, {tuple(self.y_min.shape)} do not match {n_in} -> {n_out}")
        # strains share units (the φ's each have their own); all targets share units
        self.register_buffer("x_scale", as_t(scale_of(x_min, x_max, column_groups(n_in, 6))))
        self.register_buffer("y_scale", as_t(scale_of(y_min, y_max, column_groups(n_out, n_out))))

    def scale_x(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.x_min) / self.x_scale

    def scale_y(self, y: torch.Tensor) -> torch.Tensor:
        return (y - self.y_min) / self.y_scale

    def unscale_y(self, y_scaled: torch.Tensor) -> torch.Tensor:
        return y_scaled * self.y_scale + self.y_min

    def forward_scaled(self, x_scaled: torch.Tensor) -> torch.Tensor:
        return self.net(x_scaled)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Features in physical units -> targets in physical units."""
        return self.unscale_y(self.net(self.scale_x(x)))

    def forward_members(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(forward(x), [1, n, n_out] the one member's prediction): the interface of EnsembleMLP."""
        y = self.forward(x)
        return y, y[None]

    def forward_with_tangents_members(self, x: torch.Tensor, dx: torch.Tensor):
        """(*forward_with_tangents(x, dx), [1, n, n_out] the one member's prediction)."""
        y, t = self.forward_with_tangents(x, dx)
        return y, t, y[None]

    def forward_with_tangents(self, x: torch.Tensor, dx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Targets [n, n_out] and their derivatives [n, n_out, k] along k input tangents dx [n, n_in, k].

        Forward-mode differentiation written out for the Linear/activation stack: the tangents
        are pushed through each layer as t <- act'(z) * (W t). One batched pass, no autograd
        graph: several times faster than vmap(jacrev) for the small matrices of the surrogate.
        Each point's value and its k tangents are the rows of one block z [n, 1 + k, width], so a
        layer is ONE matrix product z @ Wᵀ over n·(1+k) rows, the bias added to the value rows
        only, and the block is updated in place. (A product for the values and another for the
        tangents, each layer's results new tensors, took 1.4× as long for the default 4 × 64 tanh
        networks at the 128 Gauss points of the triaxial specimen; before that, tangents held as
        [n, width, k] were copied at every layer, 1.5× slower again at the paper mesh.)
        tanh' = 1 − tanh² reuses the layer's output. For evaluation (under torch.no_grad()): the
        in-place updates cannot be differentiated again."""
        n, n_in = x.shape
        rows = 1 + dx.shape[2]
        z = torch.empty(n, rows, n_in, dtype=x.dtype, device=x.device)
        z[:, 0] = self.scale_x(x)
        z[:, 1:] = (dx / self.x_scale[None, :, None]).transpose(1, 2)
        for layer in self.net:
            if isinstance(layer, nn.Linear):
                z = torch.mm(z.view(n * rows, -1), layer.weight.T).view(n, rows, -1)
                z[:, 0] += layer.bias
                continue
            h = z[:, 0]  # the value rows (a view of z)
            if isinstance(layer, nn.Tanh):
                h.tanh_()
                slope = 1.0 - h * h
            else:
                slope = activation_derivative(layer, h)
                h.copy_(layer(h))
            z[:, 1:] *= slope[:, None, :]
        return self.unscale_y(z[:, 0]), (z[:, 1:] * self.y_scale).transpose(1, 2)


class EnsembleMLP(nn.Module):
    """The mean of K ScaledMLP members trained on the same data from different seeds.

    The members share the min–max scaling (one training set), so the ensemble is used exactly
    like one ScaledMLP: the stress is the mean of the members' stresses and, since the mean is
    linear, its exact Jacobian is the mean of theirs. Averaging removes most of the error that
    depends on the seed of one network (docs/history.md measures it on the FEM–ML curves)."""

    def __init__(self, members: list[ScaledMLP]):
        super().__init__()
        if len(members) < 2:
            raise ValueError(f"an ensemble needs at least 2 members, got {len(members)}")
        first = members[0]
        for k, member in enumerate(members[1:], start=1):
            for name in ("x_min", "x_max", "y_min", "y_max"):
                if not np.array_equal(member.exact_scaling[name], first.exact_scaling[name]):
                    raise ValueError(f"ensemble member {k} has another scaling ({name}) than member 0")
        self.members = nn.ModuleList(members)

    # what the members share: the ensemble answers these with member 0's
    SHARED = ("x_min", "x_max", "y_min", "y_max", "x_scale", "y_scale", "exact_scaling", "scale_x", "scale_y", "unscale_y")

    def __getattr__(self, name):
        if name in EnsembleMLP.SHARED:
            return getattr(self.members[0], name)
        return super().__getattr__(name)

    def forward_scaled(self, x_scaled: torch.Tensor) -> torch.Tensor:
        return torch.stack([m.forward_scaled(x_scaled) for m in self.members]).mean(dim=0)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.unscale_y(self.forward_scaled(self.scale_x(x)))

    def forward_members(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(forward(x), [K, n, n_out] each member's prediction) from one pass of the members."""
        x_scaled = self.scale_x(x)
        scaled = torch.stack([m.forward_scaled(x_scaled) for m in self.members])
        return self.unscale_y(scaled.mean(dim=0)), self.unscale_y(scaled)

    def forward_with_tangents(self, x: torch.Tensor, dx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.forward_with_tangents_members(x, dx)[:2]

    def forward_with_tangents_members(self, x: torch.Tensor, dx: torch.Tensor):
        """(*forward_with_tangents(x, dx), [K, n, n_out] each member's prediction)."""
        values, slopes = zip(*(m.forward_with_tangents(x, dx) for m in self.members))
        values = torch.stack(values)
        return values.mean(dim=0), torch.stack(slopes).mean(dim=0), values


def _training_states(path: Path, states, n_features: int) -> np.ndarray | None:
    """The training-input sample of a model file as an array; ModelFileError when it does not fit."""
    if states is None:
        return None
    states = states.numpy() if isinstance(states, torch.Tensor) else np.asarray(states)
    if states.ndim != 2 or states.shape[1] != n_features or not np.isfinite(states).all():
        raise ModelFileError(f"{path}: training_states of shape {states.shape} do not fit its {n_features} "
                             "inputs, or are not finite")
    return states.astype(np.float64)


@dataclass
class SurrogateModel:
    network: ScaledMLP | EnsembleMLP  # one network, or an ensemble (surrogate.ensemble_size)
    kind: str  # "sigma" (NNσ) or "tangent" (ND)
    feature_names: tuple[str, ...]
    target_names: tuple[str, ...]
    architecture: dict
    config: dict = field(default_factory=dict)
    training: dict = field(default_factory=dict)
    #: mean features and targets of the fresh state (step 0) of the training points, see `initial_offset`
    initial_state: dict = field(default_factory=dict)
    #: [n, features] a sample of the training inputs (unscaled): what the material set measures a
    #: state's distance to (``novelty``); None in a model file written without it
    training_states: np.ndarray | None = None
    #: the distance beyond which a state is off those training states (``novelty.TrainingStates.radius``)
    training_radius: float | None = None

    @classmethod
    def create(cls, kind: str, history, scaling: dict, settings: dict, config: dict | None = None) -> "SurrogateModel":
        """A fresh (untrained) model; `history` as in dataset.history_selection; `settings` is the
        config's `surrogate` section."""
        feats, targs = feature_names(history), target_names(kind)
        arch = {
            "n_in": len(feats),
            "n_out": len(targs),
            "hidden_layers": int(settings["hidden_layers"]),
            "hidden_units": int(settings["hidden_units"]),
            "activation": str(settings["activation"]),
        }
        net = ScaledMLP(**arch, **{k: scaling[k] for k in ("x_min", "x_max", "y_min", "y_max")})
        return cls(net, kind, tuple(feats), tuple(targs), arch, dict(config or {}))

    @property
    def history(self) -> tuple[str, ...]:
        """The history variables among the features (empty for the ablation)."""
        return tuple(self.feature_names[len(STRAIN_FEATURES):])

    @property
    def members(self) -> list[ScaledMLP]:
        """The networks whose mean the model predicts: one, or the ensemble's K."""
        return list(self.network.members) if isinstance(self.network, EnsembleMLP) else [self.network]

    @property
    def ensemble_size(self) -> int:
        return len(self.members)

    @property
    def use_history(self) -> bool:
        return bool(self.history)

    @property
    def takes_pressure(self) -> bool:
        """Whether p0, the consolidation pressure, is an input (then FEM–ML gives it the specimen's)."""
        return takes_pressure(self.history)

    @property
    def n_features(self) -> int:
        return len(self.feature_names)

    @property
    def training_pressure(self) -> float | None:
        """Pa: the confining pressure the training RVEs were consolidated at, as training recorded it
        from its dataset; for a model file written before that record, the specimen pressure of the
        config it was trained under (a pipeline's sources share it); None if it knows neither (or its
        sources recorded none, or different ones)."""
        if "confining_pressure_Pa" in self.training:
            recorded = self.training["confining_pressure_Pa"]
            return None if recorded is None else float(recorded)
        pressure = (self.config.get("specimen") or {}).get("confining_pressure")
        return None if pressure is None else float(pressure)

    def initial_offset(self, per_member: bool = False, pressure: float | None = None) -> np.ndarray:
        """Targets minus the network's prediction at the fresh state (zero strain, zero history).

        Adding it to every prediction makes the model reproduce the initial state exactly (the
        consolidated stress, with which the specimen starts in equilibrium) whatever the fit
        error there; it is a constant, so it leaves every derivative unchanged.

        per_member: [K, n_targets], each member's own offset. Their mean is the ensemble's
        offset, so the anchored ensemble is the mean of its anchored members.

        pressure: p0 (Pa) of networks that take it. Their training recorded the fresh state at
        each pressure its RVEs were consolidated at (``initial_state["by_pressure"]``); the fresh
        state at `pressure` is the linear interpolation of those (extrapolation from the nearest
        two beyond them). The consolidated stress −p0·1 is linear in p0, so zero strain gives it
        exactly at any pressure; the fresh tangent is interpolated."""
        if not self.initial_state:
            raise ValueError("this model file records no initial state (trained by an older version)")
        state = self.initial_state
        if self.takes_pressure:
            if pressure is None or not np.isfinite(pressure):
                raise ValueError("the networks take p0: the fresh state's offset needs the consolidation pressure (Pa)")
            state = fresh_state_at(state["by_pressure"], float(pressure))
        x0 = np.asarray(state["features"], dtype=float)[None, :]
        prediction = self.predict_members(x0)[:, 0] if per_member else self.predict(x0)[0]
        return np.asarray(state["targets"], dtype=float) - prediction

    def predict(self, x: np.ndarray) -> np.ndarray:
        """[n, n_features] raw features -> [n, n_targets] raw targets (numpy, no gradient)."""
        param = next(self.network.parameters())
        with torch.no_grad():
            y = self.network(torch.as_tensor(np.asarray(x), dtype=param.dtype, device=param.device))
        return y.cpu().numpy().astype(np.float64)

    def predict_members(self, x: np.ndarray) -> np.ndarray:
        """[n, n_features] raw features -> [K, n, n_targets]: each member's prediction (K = 1 for one network)."""
        param = next(self.network.parameters())
        with torch.no_grad():
            _, y = self.network.forward_members(torch.as_tensor(np.asarray(x), dtype=param.dtype, device=param.device))
        return y.cpu().numpy().astype(np.float64)

    def save(self, path: str | Path) -> None:
        """Write weights, scaling, names, config and training summary atomically."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        net = self.network
        payload = {
            "format": FORMAT,
            "kind": self.kind,
            "feature_names": list(self.feature_names),
            "target_names": list(self.target_names),
            "architecture": dict(self.architecture),
            "scaling": {k: v.tolist() for k, v in net.exact_scaling.items()},
            # one state dict per member; a single network is a list of one
            "members": [{k: v.detach().cpu().float() for k, v in m.state_dict().items()} for m in self.members],
            "config": json.dumps(self.config),
            "training": json.dumps(self.training),
            "initial_state": json.dumps(self.initial_state),
        }
        if self.training_states is not None:
            payload["training_states"] = torch.as_tensor(np.asarray(self.training_states, dtype=np.float64))
            payload["training_radius"] = self.training_radius
        with atomic_path(path) as tmp:
            torch.save(payload, tmp)

    @classmethod
    def load(cls, path: str | Path, dtype: torch.dtype = torch.float64) -> "SurrogateModel":
        """Load a saved model (eval mode, no gradients on the weights) in `dtype` on the CPU."""
        path = Path(path)
        if not path.exists():
            raise ModelFileError(f"model file not found: {path}")
        try:  # torch.load does not check the archive's CRC: a flipped byte reads back as weights
            integrity.verify(path, "model file")
        except integrity.CorruptFileError as error:
            raise ModelFileError(str(error)) from None
        try:
            payload = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as e:  # torch raises several types for a damaged file
            raise ModelFileError(f"{path}: not a readable model file ({e})") from None
        if not isinstance(payload, dict) or payload.get("format") not in READABLE_FORMATS:
            raise ModelFileError(f"{path}: not a surrogate model file (expected format {FORMAT})")
        names = tuple(payload.get("feature_names", ()))
        history = names[len(STRAIN_FEATURES):]
        if names[: len(STRAIN_FEATURES)] != STRAIN_FEATURES or any(h not in HISTORY_FEATURES for h in history):
            raise ModelFileError(f"{path}: inputs {list(names)} are not features this project computes (the six "
                                 f"strains {list(STRAIN_FEATURES)}, then history variables from {list(HISTORY_FEATURES)})")
        arch = payload["architecture"]
        states = payload["members"] if payload["format"] == FORMAT else [payload["state_dict"]]
        members = [_load_member(path, k, arch, payload["scaling"], state, dtype) for k, state in enumerate(states)]
        net = members[0] if len(members) == 1 else EnsembleMLP(members)
        net.eval()
        net.requires_grad_(False)
        return cls(
            net,
            payload["kind"],
            tuple(payload["feature_names"]),
            tuple(payload["target_names"]),
            dict(arch),
            json.loads(payload["config"]),
            json.loads(payload["training"]),
            json.loads(payload.get("initial_state", "{}")),
            _training_states(path, payload.get("training_states"), len(names)),
            payload.get("training_radius"),
        )


def _load_member(path: Path, index: int, arch: dict, scaling: dict, state: dict, dtype: torch.dtype) -> ScaledMLP:
    """One network of a model file, its scaling buffers at full precision."""
    net = ScaledMLP(**arch, **scaling)
    # x_scale/y_scale are derived from the min/max (recomputed below): not needed in the file
    missing, unexpected = net.load_state_dict(state, strict=False)
    if unexpected or set(missing) - {"x_scale", "y_scale"}:
        raise ModelFileError(f"{path}: weights of network {index} do not fit the architecture "
                             f"(missing {missing}, unexpected {unexpected})")
    net = net.to(dtype)
    # reload the scaling buffers at full precision (they were created in float32)
    for k, v in net.exact_scaling.items():
        getattr(net, k).copy_(torch.as_tensor(v, dtype=dtype))
    net.x_scale.copy_(torch.as_tensor(scale_of(net.exact_scaling["x_min"], net.exact_scaling["x_max"],
                                               column_groups(arch["n_in"], 6)), dtype=dtype))
    net.y_scale.copy_(torch.as_tensor(scale_of(net.exact_scaling["y_min"], net.exact_scaling["y_max"],
                                               column_groups(arch["n_out"], arch["n_out"])), dtype=dtype))
    return net
