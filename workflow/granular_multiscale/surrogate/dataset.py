"""Training data of the surrogates: a reference run split by Gauss point, with min–max scaling.

Every (step, Gauss point) of the reference run of the training path is one sample:

    features  strain_11 .. strain_12 (tensorial, Voigt order of ``tensors.COMP``), phi1, phi2, phi3
    targets   stress_11 .. stress_12 (Pa, tension positive)             -> NNσ
              tangent_1111 .. tangent_1212 (21 upper-triangle entries)  -> ND

φ1–φ3 are recomputed from each point's converged strain sequence (``history.history_from_sequence``),
exactly as the surrogate material accumulates them during an FEM–ML run.

The Gauss points (not the samples) are split, seeded: a held-out point's whole history is
unseen in training, as in the paper (1500/500 points). The min–max scaling to (0, 1) is
fitted on the training points only and stored in both files, as are the lists of training
and held-out Gauss points, so figures and metrics can tell them apart.

Files (``train.h5``, ``heldout.h5``) follow the run-file contract: coordinates ``step``,
``gp`` (the original Gauss-point ids of that subset), ``comp``, ``tcomp``, ``hist``,
``feature``; variables ``strain``, ``history``, ``stress``, ``tangent``, ``gp_position``
and the scaling ``feature_min/max(feature)``, ``stress_min/max(comp)``,
``tangent_min/max(tcomp)``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import xarray as xr

from ..atomic import atomic_path
from ..history import HIST, history_from_sequence
from ..tensors import COMP, TCOMP

STRAIN_FEATURES = tuple(f"strain_{c}" for c in COMP)
HISTORY_FEATURES = HIST
FEATURES = STRAIN_FEATURES + HISTORY_FEATURES
STRESS_TARGETS = tuple(f"stress_{c}" for c in COMP)
TANGENT_TARGETS = tuple(f"tangent_{c}" for c in TCOMP)
TARGET_KINDS = ("sigma", "tangent")


class DatasetError(ValueError):
    """A reference run cannot make a dataset; the message names the file, variable, step or Gauss point."""


def history_selection(history=True) -> tuple[str, ...]:
    """Which history variables a network takes: True = φ1–φ3 (the paper), False = none (the
    ablation), or a list of names from ``history.HIST`` (config ``surrogate.history_variables``)."""
    if history is True:
        return HIST
    if history is False or history is None:
        return ()
    chosen = tuple(str(h) for h in history)
    unknown = [h for h in chosen if h not in HIST]
    if unknown or len(set(chosen)) != len(chosen):
        raise ValueError(f"config key 'surrogate.history_variables': expected distinct names from {list(HIST)}, got {list(chosen)}")
    return tuple(h for h in HIST if h in chosen)


def feature_names(history=True) -> tuple[str, ...]:
    return STRAIN_FEATURES + history_selection(history)


def target_names(kind: str) -> tuple[str, ...]:
    if kind == "sigma":
        return STRESS_TARGETS
    if kind == "tangent":
        return TANGENT_TARGETS
    raise ValueError(f"target kind must be one of {TARGET_KINDS}, got {kind!r}")


SPLITS = ("random", "cover_range")


def range_extremes(features: np.ndarray) -> np.ndarray:
    """Gauss points at which some feature of ``features[step, gp, feature]`` reaches its
    minimum or maximum over all steps and points (sorted, unique)."""
    lowest, highest = features.min(axis=0).argmin(axis=0), features.max(axis=0).argmax(axis=0)
    return np.unique(np.concatenate([lowest, highest]))


def split_gauss_points(n_gp: int, train_fraction: float, seed: int, always_train=()) -> tuple[np.ndarray, np.ndarray]:
    """Seeded random split of Gauss points 0..n_gp-1 into sorted (train, held-out) index arrays;
    the points in ``always_train`` are training points, the rest of the training set is drawn."""
    if not 0.0 < train_fraction < 1.0:
        raise ValueError(f"surrogate.train_fraction must be in (0, 1), got {train_fraction}")
    if n_gp < 2:
        raise DatasetError(f"need at least 2 Gauss points to split into train and held-out, got {n_gp}")
    n_train = min(max(int(round(train_fraction * n_gp)), 1), n_gp - 1)
    forced = np.unique(np.asarray(always_train, dtype=np.int64))
    if forced.size > n_train:
        raise DatasetError(f"{forced.size} Gauss points must train (they span the feature range) but "
                           f"surrogate.train_fraction leaves room for {n_train} of {n_gp}")
    order = np.random.default_rng(seed).permutation(n_gp)
    rest = order[~np.isin(order, forced)]
    train = np.concatenate([forced, rest[: n_train - forced.size]])
    return np.sort(train), np.sort(rest[n_train - forced.size:])


def minmax(values: np.ndarray, axis) -> tuple[np.ndarray, np.ndarray]:
    return np.min(values, axis=axis), np.max(values, axis=axis)


def _check_finite(run: xr.Dataset, name: str, source: str) -> None:
    values = run[name].values
    bad = ~np.isfinite(values)
    if bad.any():
        step_i, gp_i = np.argwhere(bad)[0][:2]
        raise DatasetError(
            f"{source}: variable '{name}' is not finite at step {run.step.values[step_i]}, "
            f"gp {run.gp.values[gp_i]} ({int(bad.any(axis=-1).sum())} (step, gp) entries in all)"
        )


def _check_contract(run: xr.Dataset, source: str) -> None:
    for name, dims in (("strain", ("step", "gp", "comp")), ("stress", ("step", "gp", "comp")), ("tangent", ("step", "gp", "tcomp"))):
        if name not in run:
            raise DatasetError(f"{source}: variable '{name}' missing (data contract: {name}{dims})")
        if tuple(run[name].dims) != dims:
            raise DatasetError(f"{source}: variable '{name}' has dims {run[name].dims}, expected {dims}")
    if [str(c) for c in run.comp.values] != list(COMP):
        raise DatasetError(f"{source}: coordinate 'comp' is {list(run.comp.values)}, expected {list(COMP)}")
    if [str(c) for c in run.tcomp.values] != list(TCOMP):
        raise DatasetError(f"{source}: coordinate 'tcomp' is {list(run.tcomp.values)}, expected {list(TCOMP)}")
    if run.sizes["step"] < 2:
        raise DatasetError(f"{source}: a dataset needs at least 2 steps, the run has {run.sizes['step']}")
    for name in ("strain", "stress", "tangent"):
        _check_finite(run, name, source)


def build_dataset(run: xr.Dataset, train_fraction: float, seed: int, source: str = "reference run",
                  split: str = "random") -> tuple[xr.Dataset, xr.Dataset]:
    """Reference run (data contract) -> (train, held-out) datasets with the train-fitted scaling.

    split: 'random' draws the training points (the paper); 'cover_range' first puts every point
    at which a feature reaches its minimum or maximum into the training set, so the min–max
    scaling spans what the specimen does; the rest is drawn as before."""
    if split not in SPLITS:
        raise ValueError(f"surrogate.split must be one of {SPLITS}, got {split!r}")
    _check_contract(run, source)
    run = run.transpose("step", "gp", ...)
    strain = run["strain"].values
    history = history_from_sequence(strain)  # [step, gp, 3], φ of each converged step
    stress = run["stress"].values
    tangent = run["tangent"].values
    n_gp = run.sizes["gp"]
    features = np.concatenate([strain, history], axis=-1)
    always_train = range_extremes(features) if split == "cover_range" else ()
    train_idx, heldout_idx = split_gauss_points(n_gp, train_fraction, seed, always_train)
    gp_ids = run.gp.values

    f_min, f_max = minmax(features[:, train_idx].reshape(-1, len(FEATURES)), axis=0)
    s_min, s_max = minmax(stress[:, train_idx].reshape(-1, 6), axis=0)
    t_min, t_max = minmax(tangent[:, train_idx].reshape(-1, 21), axis=0)

    base = xr.Dataset(
        {
            "strain": (("step", "gp", "comp"), strain, {"units": "1", "long_name": "total strain, tensorial shear"}),
            "history": (("step", "gp", "hist"), history, {"units": "1", "long_name": "history variables φ1–φ3 of the converged strain sequence"}),
            "stress": (("step", "gp", "comp"), stress, {"units": "Pa", "long_name": "Cauchy stress, tension positive"}),
            "tangent": (("step", "gp", "tcomp"), tangent, {"units": "Pa", "long_name": "upper triangle of the 6×6 Voigt tangent on engineering strain" + (
                # a run whose tangent is not symmetric stores its symmetric part here (data module)
                "; the symmetric part of the run's non-symmetric tangent (tangent_full)" if "tangent_full" in run else "")}),
            "feature_min": (("feature",), f_min, {"long_name": "minimum of each feature over the training points"}),
            "feature_max": (("feature",), f_max, {"long_name": "maximum of each feature over the training points"}),
            "stress_min": (("comp",), s_min, {"units": "Pa"}),
            "stress_max": (("comp",), s_max, {"units": "Pa"}),
            "tangent_min": (("tcomp",), t_min, {"units": "Pa"}),
            "tangent_max": (("tcomp",), t_max, {"units": "Pa"}),
        },
        coords={
            "step": run.step.values,
            "gp": gp_ids,
            "comp": list(COMP),
            "tcomp": list(TCOMP),
            "hist": list(HIST),
            "feature": list(FEATURES),
        },
    )
    for name in ("gp_position", "axial_strain", "phase", "top_force", "volumetric_strain"):
        if name in run:
            base[name] = run[name]
    attrs = {
        "title": "surrogate dataset",
        "source": str(source),
        "source_method": str(run.attrs.get("method", "")),
        "seed": int(seed),
        "train_fraction": float(train_fraction),
        "split_method": split,
        "range_extreme_gp": gp_ids[np.asarray(always_train, dtype=np.int64)].astype(np.int64),
        "train_gp": gp_ids[train_idx].astype(np.int64),
        "heldout_gp": gp_ids[heldout_idx].astype(np.int64),
        "scaling": "min–max to (0, 1) fitted on the training Gauss points: x_scaled = (x - min) / (max - min)",
        "history_definition": "Δε_acc = Σ_k |ε(k) − ε(k−1)|; φ1 = Frobenius norm (off-diagonals twice), φ2 = trace, φ3 = product of the six components",
    }
    if "config" in run.attrs:
        attrs["source_config"] = run.attrs["config"]
    train = base.isel(gp=train_idx).assign_attrs(attrs, split="train")
    heldout = base.isel(gp=heldout_idx).assign_attrs(attrs, split="heldout")
    return train, heldout


def write_dataset(ds: xr.Dataset, path: str | Path) -> None:
    """Write atomically (temporary file in the target folder, then rename)."""
    with atomic_path(path) as tmp:
        ds.to_netcdf(tmp, engine="h5netcdf")


def read_dataset(path: str | Path) -> xr.Dataset:
    path = Path(path)
    if not path.exists():
        raise DatasetError(f"dataset file not found: {path}")
    try:
        with xr.open_dataset(path, engine="h5netcdf") as ds:
            ds = ds.load()
    except (OSError, ValueError) as error:  # h5py/h5netcdf on a damaged or truncated file
        raise DatasetError(f"{path}: not a readable dataset file ({error})") from None
    for name in ("strain", "history", "stress", "tangent", "feature_min", "feature_max"):
        if name not in ds:
            raise DatasetError(f"{path}: variable '{name}' missing; not a surrogate dataset")
    return ds


def features(ds: xr.Dataset, history=True) -> np.ndarray:
    """[step·gp, 6 + n_history] raw feature matrix, samples ordered step-major (see history_selection)."""
    parts = [ds["strain"].transpose("step", "gp", "comp").values]
    chosen = history_selection(history)
    if chosen:
        parts.append(ds["history"].sel(hist=list(chosen)).transpose("step", "gp", "hist").values)
    x = np.concatenate(parts, axis=-1)
    return x.reshape(-1, x.shape[-1])


def targets(ds: xr.Dataset, kind: str) -> np.ndarray:
    """[step·gp, 6] stresses or [step·gp, 21] tangent entries, samples ordered as :func:`features`."""
    target_names(kind)
    var, last = ("stress", "comp") if kind == "sigma" else ("tangent", "tcomp")
    y = ds[var].transpose("step", "gp", last).values
    return y.reshape(-1, y.shape[-1])


def scaling(ds: xr.Dataset, kind: str, history=True) -> dict[str, np.ndarray]:
    """Feature and target min/max stored with the dataset (fitted on the training points)."""
    names = list(feature_names(history))
    var = "stress" if kind == "sigma" else "tangent"
    target_names(kind)
    return {
        "x_min": ds["feature_min"].sel(feature=names).values,
        "x_max": ds["feature_max"].sel(feature=names).values,
        "y_min": ds[f"{var}_min"].values,
        "y_max": ds[f"{var}_max"].values,
    }


def split_of(ds: xr.Dataset) -> dict[str, np.ndarray]:
    """{'train': gp ids, 'heldout': gp ids} recorded in a dataset file."""
    return {"train": np.asarray(ds.attrs["train_gp"]).ravel(), "heldout": np.asarray(ds.attrs["heldout_gp"]).ravel()}


def summary(train: xr.Dataset, heldout: xr.Dataset) -> str:
    return json.dumps(
        {
            "train_gp": int(train.sizes["gp"]),
            "heldout_gp": int(heldout.sizes["gp"]),
            "split_method": str(train.attrs.get("split_method", "random")),
            "range_extreme_gp": int(len(np.atleast_1d(train.attrs.get("range_extreme_gp", [])))),
            "steps": int(train.sizes["step"]),
            "train_samples": int(train.sizes["gp"] * train.sizes["step"]),
            "heldout_samples": int(heldout.sizes["gp"] * heldout.sizes["step"]),
        }
    )
