"""Training data of the surrogates: reference runs and RVE-path sets, held out by trajectory, min–max scaled.

Every (step, trajectory) of every training source is one sample:

    features  strain_11 .. strain_12 (tensorial, Voigt order of ``tensors.COMP``), and those of
              phi1, phi2, phi3, psi1, psi2 (``history.HIST``) and p0 that ``surrogate.history_variables``
              selects
    targets   stress_11 .. stress_12 (Pa, tension positive)             -> NNσ
              tangent_1111 .. tangent_1212 (21 upper-triangle entries)  -> ND

A *trajectory* is one Gauss point of a reference run (FEM–DEM or the elastoplastic model) or
one RVE of an RVE-path set (``dem.strain_paths``). The history variables (φ1–φ3, ψ1, ψ2) are
recomputed from each trajectory's strain sequence (``history.history_from_sequence``), exactly as
the surrogate material accumulates them during an FEM–ML run; a dataset holds all of them, the
networks take the selected ones. p0 (``CONSOLIDATION_PRESSURE``) is the mean stress (Pa) the RVE was
consolidated at, the one history variable that its preparation, not its strain path, writes: it
is constant along a trajectory, recorded by its source (:func:`source_pressure`), and lets one
pair of networks answer for specimens prepared at other pressures.

Held out by trajectory class. On a symmetric mesh with one packing, mirrored Gauss points follow
the same strain history; a held-out mirror image of a training point is a copy, not a test.
:func:`trajectory_classes` groups the trajectories of a source whose histories agree, in the
invariants of the square cross-section's symmetry, within ``surrogate.history_tolerance`` of the
source's largest strain; :func:`split_trajectories` then holds out whole classes (seeded, per
source, so every source is on both sides). Split ``cover_range`` looks at the strains and φ1–φ3
only, so adding ψ1, ψ2 did not change the split of any existing configuration; a ψ maximum that
lands on the held-out side shows up in FEM–ML's out-of-range count. The min–max scaling to (0, 1) is fitted on the
training samples only.

Files (``train.h5``, ``heldout.h5``) follow the run-file contract: coordinates ``step``, ``gp``
(the trajectory: with one run as the only source, its Gauss-point id; otherwise a running index),
``comp``, ``tcomp``, ``hist``, ``feature``, and per trajectory ``source`` (file), ``source_gp``
(Gauss point or RVE in that file) and ``trajectory_class``; variables ``strain``, ``history``,
``stress``, ``tangent``, ``consolidation_pressure(gp)``, ``valid(step, gp)`` (False on the padding of a source with fewer steps
and after an RVE lost its contact network), ``gp_position`` (run sources) and the scaling
``feature_min/max(feature)``, ``stress_min/max(comp)``, ``tangent_min/max(tcomp)``. Attrs
``train_gp``/``heldout_gp``: the mesh Gauss points of the run sources on each side (what the
error maps of a validation run on the same mesh colour).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import xarray as xr

from .. import integrity
from ..atomic import atomic_path
from ..history import HIST, PHI, history_from_sequence
from ..tensors import COMP, TCOMP

STRAIN_FEATURES = tuple(f"strain_{c}" for c in COMP)
#: the history variable of the preparation: the mean stress (Pa) the RVE was consolidated at
CONSOLIDATION_PRESSURE = "p0"
HISTORY_FEATURES = HIST + (CONSOLIDATION_PRESSURE,)
FEATURES = STRAIN_FEATURES + HISTORY_FEATURES
STRESS_TARGETS = tuple(f"stress_{c}" for c in COMP)
TANGENT_TARGETS = tuple(f"tangent_{c}" for c in TCOMP)
TARGET_KINDS = ("sigma", "tangent")


class DatasetError(ValueError):
    """A reference run cannot make a dataset; the message names the file, variable, step or Gauss point."""


#: sources whose gp are trajectories, not the Gauss points of one mesh run: RVE-path sets and the
#: DEM points of an adaptive run (their ids are not counted as train_gp/heldout_gp mesh points)
TRAJECTORY_SETS = ("rve_paths", "adaptive_dem")


def history_selection(history=True) -> tuple[str, ...]:
    """Which history variables a network takes: True = φ1–φ3 (the paper), False = none (the
    ablation), or a list of names from ``HISTORY_FEATURES`` (config ``surrogate.history_variables``),
    returned in that order (p0 last)."""
    if history is True:
        return PHI
    if history is False or history is None:
        return ()
    chosen = tuple(str(h) for h in history)
    unknown = [h for h in chosen if h not in HISTORY_FEATURES]
    if unknown or len(set(chosen)) != len(chosen):
        raise ValueError("config key 'surrogate.history_variables': expected distinct names from "
                         f"{list(HISTORY_FEATURES)}, got {list(chosen)}")
    return tuple(h for h in HISTORY_FEATURES if h in chosen)


def strain_history(history) -> tuple[str, ...]:
    """The selected history variables that the strain path writes (``history.HIST``): all but p0."""
    return tuple(h for h in history_selection(history) if h in HIST)


def takes_pressure(history) -> bool:
    """Whether the selection includes p0, the consolidation pressure."""
    return CONSOLIDATION_PRESSURE in history_selection(history)


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
    return split_trajectories(np.arange(n_gp), train_fraction, seed, always_train)


def split_trajectories(classes: np.ndarray, train_fraction: float, seed: int, always_train=()) -> tuple[np.ndarray, np.ndarray]:
    """Seeded split of trajectories 0..n-1 with class labels ``classes[n]`` into sorted (train,
    held-out) index arrays that never cut a class: whole classes are drawn (in a seeded random
    order) until the training side holds ``train_fraction`` of the trajectories. The classes of the
    trajectories in ``always_train`` train. With every trajectory its own class this is the
    paper's split by Gauss point."""
    if not 0.0 < train_fraction < 1.0:
        raise ValueError(f"surrogate.train_fraction must be in (0, 1), got {train_fraction}")
    classes = np.asarray(classes)
    n = classes.size
    labels, inverse = np.unique(classes, return_inverse=True)
    if labels.size < 2:
        raise DatasetError(f"need at least 2 distinct trajectories to split into train and held-out, got {labels.size} "
                           f"(of {n} trajectories)")
    n_train = min(max(int(round(train_fraction * n)), 1), n - 1)
    forced = np.unique(inverse[np.asarray(always_train, dtype=np.int64)])
    sizes = np.bincount(inverse, minlength=labels.size)
    if sizes[forced].sum() > n_train:
        raise DatasetError(f"{sizes[forced].sum()} trajectories must train (they span the feature range) but "
                           f"surrogate.train_fraction leaves room for {n_train} of {n}")
    order = np.random.default_rng(seed).permutation(labels.size)
    chosen = list(forced)
    count = int(sizes[forced].sum())
    for c in order[~np.isin(order, forced)]:
        if count >= n_train:
            break
        if count + sizes[c] <= n_train or count == 0:
            chosen.append(c)
            count += sizes[c]
    if len(chosen) == labels.size:  # one class holds nearly everything: keep one class out
        chosen.remove(max(set(chosen) - set(forced), key=lambda c: -sizes[c]))
    train = np.isin(inverse, chosen)
    return np.flatnonzero(train), np.flatnonzero(~train)


def symmetry_invariants(strain: np.ndarray) -> np.ndarray:
    """[step, gp, 6] strain invariants under the square cross-section's symmetries (mirror x, mirror
    y, swap x and y): ε33, ε11 + ε22, |ε11 − ε22|, |ε12|, and the smaller and larger of |ε13|, |ε23|."""
    e = np.asarray(strain)
    a13, a23 = np.abs(e[..., 4]), np.abs(e[..., 3])
    return np.stack([e[..., 2], e[..., 0] + e[..., 1], np.abs(e[..., 0] - e[..., 1]), np.abs(e[..., 5]),
                     np.minimum(a13, a23), np.maximum(a13, a23)], axis=-1)


def trajectory_classes(strain: np.ndarray, tolerance: float) -> np.ndarray:
    """Class label per trajectory of ``strain[step, gp, 6]``: trajectories whose symmetry invariants
    differ by less than ``tolerance`` × (largest |strain| of the set) at every step are one class
    (and, transitively, their neighbours: single linkage). Labels 0..k-1 in order of first member."""
    inv = symmetry_invariants(strain).transpose(1, 0, 2).reshape(strain.shape[1], -1)
    scale = float(np.abs(strain).max()) or 1.0
    parent = np.arange(inv.shape[0])

    def root(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i in range(inv.shape[0] - 1):  # row by row: memory O(n), fine for the paper's 2000 points
        close = np.flatnonzero(np.abs(inv[i + 1:] - inv[i]).max(axis=1) < tolerance * scale) + i + 1
        for j in close:
            ri, rj = root(i), root(j)
            if ri != rj:
                parent[max(ri, rj)] = min(ri, rj)
    roots = np.array([root(i) for i in range(inv.shape[0])])
    return np.unique(roots, return_inverse=True)[1]


def minmax(values: np.ndarray, axis) -> tuple[np.ndarray, np.ndarray]:
    return np.min(values, axis=axis), np.max(values, axis=axis)


def _check_finite(run: xr.Dataset, name: str, source: str, valid: np.ndarray | None = None) -> None:
    values = run[name].values
    bad = ~np.isfinite(values)
    if valid is not None:
        bad &= valid.reshape(valid.shape + (1,) * (bad.ndim - valid.ndim))
    if bad.any():
        step_i, gp_i = np.argwhere(bad)[0][:2]
        raise DatasetError(
            f"{source}: variable '{name}' is not finite at step {run.step.values[step_i]}, "
            f"gp {run.gp.values[gp_i]} ({int(bad.any(axis=-1).sum())} (step, gp) entries in all)"
        )


def _valid_of(run: xr.Dataset) -> np.ndarray:
    """[step, gp] samples a source offers: all, or those its ``valid`` marks (an RVE-path set marks
    the steps after an RVE lost its contact network)."""
    if "valid" in run:
        return run["valid"].transpose("step", "gp").values.astype(bool)
    return np.ones((run.sizes["step"], run.sizes["gp"]), dtype=bool)


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
    if run.sizes["gp"] == 0:
        raise DatasetError(f"{source}: no trajectories (an adaptive run that promoted no point has no DEM "
                           "answers to learn from: lower adaptive.active_learning.threshold)")
    valid = _valid_of(run)
    _check_finite(run, "strain", source)
    for name in ("stress", "tangent"):
        _check_finite(run, name, source, valid)


def _pad(values: np.ndarray, n_steps: int, fill) -> np.ndarray:
    """Extend [step, ...] to n_steps along the step axis: ``fill`` = 'last' repeats the last step."""
    missing = n_steps - values.shape[0]
    if missing <= 0:
        return values
    tail = np.repeat(values[-1:], missing, axis=0) if isinstance(fill, str) else np.full((missing, *values.shape[1:]), fill)
    return np.concatenate([values, tail.astype(values.dtype)])


def source_pressure(run: xr.Dataset) -> float | None:
    """Pa: the confining pressure a source's material points were consolidated at, as the source
    records it (a FEM run's or an adaptive run's RVEs' ``confining_pressure_Pa``, an RVE-path set's
    ``confining_pressure``); None if it records none."""
    for key in ("confining_pressure_Pa", "confining_pressure"):
        if key in run.attrs:
            return float(run.attrs[key])
    return None


def build_dataset(run: xr.Dataset, train_fraction: float, seed: int, source: str = "reference run",
                  split: str = "random", history_tolerance: float = 0.0) -> tuple[xr.Dataset, xr.Dataset]:
    """One reference run (data contract) -> (train, held-out) datasets; see :func:`build_dataset_from_sources`.
    ``history_tolerance`` 0 makes every Gauss point its own class (the paper's split by point)."""
    return build_dataset_from_sources([(source, run)], train_fraction, seed, split=split,
                                      history_tolerance=history_tolerance)


def build_dataset_from_sources(sources, train_fraction: float, seed: int, split: str = "random",
                               history_tolerance: float = 0.02) -> tuple[xr.Dataset, xr.Dataset]:
    """Training sources [(name, Dataset)] -> (train, held-out) datasets with the train-fitted scaling.

    Each source is a reference run or an RVE-path set (one ``gp`` per trajectory). Trajectories
    are grouped into classes of equal history (:func:`trajectory_classes`, per source) and the
    classes are split per source (:func:`split_trajectories`), seeded by ``seed`` + source index.
    split: 'random' draws the training classes; 'cover_range' first puts every class holding a
    trajectory at which a feature reaches its minimum or maximum into training, so the min–max
    scaling spans what the sources do. Sources with fewer steps are padded (``valid`` False)."""
    if split not in SPLITS:
        raise ValueError(f"surrogate.split must be one of {SPLITS}, got {split!r}")
    if not sources:
        raise DatasetError("no training sources (config key 'surrogate.training_sources')")
    n_steps = max(run.sizes["step"] for _, run in sources)
    parts = {k: [] for k in ("strain", "history", "stress", "tangent", "valid", "source", "source_gp", "klass", "train",
                             "position", "is_run", "pressure")}
    n_classes, offset, extremes = 0, 0, []
    for k, (name, run) in enumerate(sources):
        _check_contract(run, name)
        run = run.transpose("step", "gp", ...)
        strain = run["strain"].values
        valid = _valid_of(run)
        stress = np.where(valid[..., None], run["stress"].values, np.nan)
        tangent = np.where(valid[..., None], run["tangent"].values, np.nan)
        history = history_from_sequence(strain)  # [step, gp, 5], HIST of each converged step
        classes = (trajectory_classes(strain, history_tolerance) if history_tolerance > 0
                   else np.arange(run.sizes["gp"]))
        covered = np.concatenate([strain, history[..., [HIST.index(h) for h in PHI]]], axis=-1)  # not ψ: docstring
        always = range_extremes(np.where(valid[..., None], covered, np.nan)) if split == "cover_range" else ()
        train_idx, _ = split_trajectories(classes, train_fraction, seed + k, always)
        is_train = np.zeros(run.sizes["gp"], dtype=bool)
        is_train[train_idx] = True
        is_run = str(run.attrs.get("method", "")) not in TRAJECTORY_SETS
        for key, values in (("strain", _pad(strain, n_steps, "last")), ("history", _pad(history, n_steps, "last")),
                            ("stress", _pad(stress, n_steps, np.nan)), ("tangent", _pad(tangent, n_steps, np.nan)),
                            ("valid", _pad(valid, n_steps, False))):
            parts[key].append(values)
        parts["source"].append(np.full(run.sizes["gp"], str(name), dtype=object))
        parts["source_gp"].append(run.gp.values.astype(np.int64))
        parts["klass"].append(classes + n_classes)
        parts["train"].append(is_train)
        parts["is_run"].append(np.full(run.sizes["gp"], is_run))
        pressure = source_pressure(run)  # NaN where the source records none: p0 cannot be a feature then
        parts["pressure"].append(np.full(run.sizes["gp"], np.nan if pressure is None else pressure))
        parts["position"].append(run["gp_position"].transpose("gp", ...).values if "gp_position" in run
                                 else np.full((run.sizes["gp"], 3), np.nan))
        extremes.extend(offset + np.asarray(always, dtype=np.int64))
        n_classes += int(classes.max()) + 1
        offset += run.sizes["gp"]
    cat = {k: np.concatenate(v, axis=1 if k in ("strain", "history", "stress", "tangent", "valid") else 0)
           for k, v in parts.items()}
    train_idx, heldout_idx = np.flatnonzero(cat["train"]), np.flatnonzero(~cat["train"])
    valid = cat["valid"]

    def train_minmax(values):
        samples = values[:, train_idx][valid[:, train_idx]]
        return minmax(samples, axis=0)

    pressure_column = np.broadcast_to(cat["pressure"][None, :, None], (n_steps, cat["pressure"].size, 1))
    features_all = np.concatenate([cat["strain"], cat["history"], pressure_column], axis=-1)
    f_min, f_max = train_minmax(features_all)
    s_min, s_max = train_minmax(cat["stress"])
    t_min, t_max = train_minmax(cat["tangent"])
    one_run = len(sources) == 1 and bool(cat["is_run"][0])
    gp_ids = cat["source_gp"] if one_run else np.arange(cat["source_gp"].size)
    first = sources[0][1]
    base = xr.Dataset(
        {
            "strain": (("step", "gp", "comp"), cat["strain"], {"units": "1", "long_name": "total strain, tensorial shear"}),
            "history": (("step", "gp", "hist"), cat["history"], {"units": "1", "long_name": "history variables φ1–φ3, ψ1, ψ2 of the converged strain sequence"}),
            "stress": (("step", "gp", "comp"), cat["stress"], {"units": "Pa", "long_name": "Cauchy stress, tension positive"}),
            "tangent": (("step", "gp", "tcomp"), cat["tangent"], {"units": "Pa", "long_name": "upper triangle of the 6×6 Voigt tangent on engineering strain" + (
                # a run whose tangent is not symmetric stores its symmetric part here (data module)
                "; the symmetric part of the run's non-symmetric tangent (tangent_full)" if any("tangent_full" in r for _, r in sources) else "")}),
            "valid": (("step", "gp"), valid, {"long_name": "the sample exists (not padding, RVE still in contact)"}),
            "gp_position": (("gp", "xyz"), cat["position"], {"units": "m", "long_name": "Gauss-point position (NaN for an RVE path)"}),
            "consolidation_pressure": (("gp",), cat["pressure"], {"units": "Pa", "long_name": "mean stress the RVE was consolidated at, history variable p0 (NaN: its source records none)"}),
            "feature_min": (("feature",), f_min, {"long_name": "minimum of each feature over the training samples"}),
            "feature_max": (("feature",), f_max, {"long_name": "maximum of each feature over the training samples"}),
            "stress_min": (("comp",), s_min, {"units": "Pa"}),
            "stress_max": (("comp",), s_max, {"units": "Pa"}),
            "tangent_min": (("tcomp",), t_min, {"units": "Pa"}),
            "tangent_max": (("tcomp",), t_max, {"units": "Pa"}),
        },
        coords={
            "step": np.arange(n_steps) if len(sources) > 1 else first.step.values,
            "gp": gp_ids,
            "comp": list(COMP),
            "tcomp": list(TCOMP),
            "hist": list(HIST),
            "feature": list(FEATURES),
            "xyz": ["x", "y", "z"],
            "source": ("gp", cat["source"].astype(str)),
            "source_gp": ("gp", cat["source_gp"]),
            "trajectory_class": ("gp", cat["klass"]),
        },
    )
    if one_run:
        for name in ("axial_strain", "phase", "top_force", "volumetric_strain"):
            if name in first:
                base[name] = first[name]
    mesh_points = lambda idx: np.unique(cat["source_gp"][idx][cat["is_run"][idx]]).astype(np.int64)  # noqa: E731
    attrs = {
        "title": "surrogate dataset",
        "source": ", ".join(str(n) for n, _ in sources),
        "source_method": ", ".join(str(r.attrs.get("method", "")) for _, r in sources),
        "seed": int(seed),
        "train_fraction": float(train_fraction),
        "split_method": split,
        "history_tolerance": float(history_tolerance),
        "trajectory_classes": int(n_classes),
        "range_extreme_gp": gp_ids[np.asarray(extremes, dtype=np.int64)].astype(np.int64),
        "train_gp": mesh_points(train_idx),
        "heldout_gp": mesh_points(heldout_idx),
        "scaling": "min–max to (0, 1) fitted on the training samples: x_scaled = (x - min) / (max - min)",
        "history_definition": "Δε_acc = Σ_k |ε(k) − ε(k−1)|; φ1 = Frobenius norm (off-diagonals twice), φ2 = trace, "
                              "φ3 = product of the six components; ψ1 = max_k ‖ε(k)‖_F, ψ2 = max_k ‖dev ε(k)‖_F",
    }
    if "config" in first.attrs:
        attrs["source_config"] = first.attrs["config"]
    # what the networks will take for their pressure: one, when every source that records one agrees
    pressures = {p for p in (source_pressure(run) for _, run in sources) if p is not None}
    if len(pressures) == 1:
        attrs["confining_pressure_Pa"] = pressures.pop()
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
        integrity.verify(path, "dataset file")
    except integrity.CorruptFileError as error:
        raise DatasetError(str(error)) from None
    try:
        with xr.open_dataset(path, engine="h5netcdf") as ds:
            ds = ds.load()
    except (OSError, ValueError) as error:  # h5py/h5netcdf on a damaged or truncated file
        raise DatasetError(f"{path}: not a readable dataset file ({error})") from None
    for name in ("strain", "history", "stress", "tangent", "feature_min", "feature_max"):
        if name not in ds:
            raise DatasetError(f"{path}: variable '{name}' missing; not a surrogate dataset")
    return ds


def sample_mask(ds: xr.Dataset) -> np.ndarray:
    """[step·gp] which (step, trajectory) entries are samples (``valid``; all in an older file)."""
    return _valid_of(ds).reshape(-1)


def _held(ds: xr.Dataset, chosen) -> tuple[str, ...]:
    """`chosen` history variables, checked to be in the dataset (one written before ψ1, ψ2 existed holds φ1–φ3 only)."""
    missing = [h for h in chosen if h not in ds["hist"].values]
    if missing:
        raise DatasetError(f"dataset ({ds.attrs.get('split', '?')} split of {ds.attrs.get('source', '?')}) has no history "
                           f"variables {missing} (it holds {[str(h) for h in ds['hist'].values]}); rebuild it "
                           "(rule surrogate_dataset) for config key 'surrogate.history_variables'")
    return tuple(chosen)


def sample_trajectories(ds: xr.Dataset) -> np.ndarray:
    """[samples] the trajectory of each sample (its position along ``gp``: a Gauss point of a
    reference run, or an RVE-path trajectory), samples ordered as :func:`features` orders them."""
    n_steps, n_gp = ds.sizes["step"], ds.sizes["gp"]
    return np.broadcast_to(np.arange(n_gp), (n_steps, n_gp)).reshape(-1)[sample_mask(ds)]


def features(ds: xr.Dataset, history=True) -> np.ndarray:
    """[samples, 6 + n_history] raw feature matrix, samples ordered step-major, the valid ones only
    (see history_selection, sample_mask)."""
    parts = [ds["strain"].transpose("step", "gp", "comp").values]
    chosen = strain_history(history)
    if chosen:
        parts.append(ds["history"].sel(hist=list(_held(ds, chosen))).transpose("step", "gp", "hist").values)
    if takes_pressure(history):
        pressure = consolidation_pressures(ds)
        parts.append(np.broadcast_to(pressure[None, :, None], (ds.sizes["step"], pressure.size, 1)))
    x = np.concatenate(parts, axis=-1)
    return x.reshape(-1, x.shape[-1])[sample_mask(ds)]


def consolidation_pressures(ds: xr.Dataset) -> np.ndarray:
    """[gp] p0 of each trajectory (Pa); DatasetError naming a source that records none."""
    if "consolidation_pressure" not in ds:
        raise DatasetError(f"dataset ({ds.attrs.get('split', '?')} split of {ds.attrs.get('source', '?')}) records no "
                           "consolidation pressure; rebuild it (rule surrogate_dataset) for the history variable p0")
    pressure = ds["consolidation_pressure"].values
    unknown = ~np.isfinite(pressure)
    if unknown.any():
        sources = sorted({str(s) for s in ds["source"].values[unknown]}) if "source" in ds.coords else ["the run"]
        raise DatasetError(f"history variable p0: the training sources {sources} record no confining pressure "
                           "(attribute confining_pressure_Pa or confining_pressure)")
    return pressure


def targets(ds: xr.Dataset, kind: str) -> np.ndarray:
    """[samples, 6] stresses or [samples, 21] tangent entries, samples as :func:`features`."""
    target_names(kind)
    var, last = ("stress", "comp") if kind == "sigma" else ("tangent", "tcomp")
    y = ds[var].transpose("step", "gp", last).values
    return y.reshape(-1, y.shape[-1])[sample_mask(ds)]


def scaling(ds: xr.Dataset, kind: str, history=True) -> dict[str, np.ndarray]:
    """Feature and target min/max stored with the dataset (fitted on the training points)."""
    _held(ds, strain_history(history))
    if takes_pressure(history):
        consolidation_pressures(ds)
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
    per_source = {}
    for side, ds in (("train", train), ("heldout", heldout)):
        for name in np.unique(ds["source"].values) if "source" in ds.coords else ["(one run)"]:
            sel = ds.isel(gp=ds["source"].values == name) if "source" in ds.coords else ds
            entry = per_source.setdefault(str(name), {})
            entry[f"{side}_trajectories"] = int(sel.sizes["gp"])
            entry[f"{side}_classes"] = int(np.unique(sel["trajectory_class"].values).size) if "trajectory_class" in sel.coords else None
            entry[f"{side}_samples"] = int(sample_mask(sel).sum())
    return json.dumps(
        {
            "train_trajectories": int(train.sizes["gp"]),
            "heldout_trajectories": int(heldout.sizes["gp"]),
            "split_method": str(train.attrs.get("split_method", "random")),
            "history_tolerance": float(train.attrs.get("history_tolerance", 0.0)),
            "steps": int(train.sizes["step"]),
            "train_samples": int(sample_mask(train).sum()),
            "heldout_samples": int(sample_mask(heldout).sum()),
            "sources": per_source,
        }
    )
