"""Surrogate dataset: held out by trajectory class, scaling fitted on training points, features/targets, files."""

import numpy as np
import pytest
import xarray as xr

from granular_multiscale.config import validate_config
from granular_multiscale.history import HIST, PHI, history_from_sequence
from granular_multiscale.materials.elastoplastic import Elastoplastic
from granular_multiscale.paths import load_paths_from_config
from granular_multiscale.surrogate.dataset import (
    FEATURES,
    STRAIN_FEATURES,
    TANGENT_TARGETS,
    DatasetError,
    build_dataset,
    build_dataset_from_sources,
    features,
    range_extremes,
    read_dataset,
    scaling,
    split_gauss_points,
    split_of,
    split_trajectories,
    targets,
    trajectory_classes,
    write_dataset,
)
from granular_multiscale.surrogate.synthetic import material_point_run, triaxial_strain_paths
from granular_multiscale.tensors import COMP, TCOMP, tangent_to_upper


@pytest.fixture(scope="module")
def run():
    config = validate_config({"reference_material": "elastoplastic"})
    path = load_paths_from_config(config)["path1"]
    n = 20
    return material_point_run(Elastoplastic.from_config(n, config), triaxial_strain_paths(path, n, seed=4), path)


def test_split_is_seeded_disjoint_and_complete():
    train, heldout = split_gauss_points(2000, 0.75, seed=7)
    assert (train.size, heldout.size) == (1500, 500)  # the paper's 1500/500
    assert np.intersect1d(train, heldout).size == 0
    np.testing.assert_array_equal(np.sort(np.concatenate([train, heldout])), np.arange(2000))
    again, _ = split_gauss_points(2000, 0.75, seed=7)
    np.testing.assert_array_equal(train, again)
    other, _ = split_gauss_points(2000, 0.75, seed=8)
    assert not np.array_equal(train, other)
    # never an empty side, even for tiny meshes
    t, h = split_gauss_points(2, 0.99, seed=0)
    assert (t.size, h.size) == (1, 1)
    with pytest.raises(ValueError, match="train_fraction"):
        split_gauss_points(10, 1.0, seed=0)


def test_range_extremes_and_a_split_that_keeps_them_in_training():
    values = np.zeros((3, 6, 2))  # [step, gp, feature]
    values[1, 4, 0], values[2, 1, 0] = 5.0, -2.0  # feature 0: max at gp 4, min at gp 1
    values[0, 2, 1], values[1, 3, 1] = 1.0, -1.0  # feature 1: max at gp 2, min at gp 3
    np.testing.assert_array_equal(range_extremes(values), [1, 2, 3, 4])
    for seed in range(5):
        train, heldout = split_gauss_points(6, 0.7, seed, always_train=[1, 2, 3, 4])
        assert set(train) >= {1, 2, 3, 4} and train.size == 4 and heldout.size == 2
        np.testing.assert_array_equal(np.sort(np.concatenate([train, heldout])), np.arange(6))
    with pytest.raises(DatasetError, match="5 trajectories must train .* room for 4 of 6"):
        split_gauss_points(6, 0.7, 0, always_train=[0, 1, 2, 3, 4])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_cover_range_split_scales_over_the_whole_specimen(run, seed):
    """With split cover_range the training min–max equals that of all points; a random split
    of the same seed may be narrower, never wider."""
    train, heldout = build_dataset(run, 0.75, seed=seed, split="cover_range")
    everything = np.concatenate([run.strain.values, history_from_sequence(run.strain.values)], axis=-1)
    computed = train.feature[: everything.shape[-1]]  # the strains and φ1..ψ2; then p0, which this run records not
    np.testing.assert_array_equal(train.feature_min.sel(feature=computed).values, everything.min(axis=(0, 1)))
    np.testing.assert_array_equal(train.feature_max.sel(feature=computed).values, everything.max(axis=(0, 1)))
    assert np.isnan(train.feature_min.sel(feature="p0")) and np.isnan(train.feature_max.sel(feature="p0"))
    assert set(train.attrs["range_extreme_gp"]) <= set(train.gp.values) and train.attrs["split_method"] == "cover_range"
    # the extremes are those of the strains and φ1–φ3 (ψ1, ψ2 left out: the split φ-only configs had)
    np.testing.assert_array_equal(train.attrs["range_extreme_gp"], run.gp.values[range_extremes(everything[..., :9])])
    assert (train.sizes["gp"], heldout.sizes["gp"]) == (15, 5)
    drawn, _ = build_dataset(run, 0.75, seed=seed)
    assert np.all(drawn.feature_max.sel(feature=computed).values - drawn.feature_min.sel(feature=computed).values
                  <= train.feature_max.sel(feature=computed).values - train.feature_min.sel(feature=computed).values)
    with pytest.raises(ValueError, match="surrogate.split"):
        build_dataset(run, 0.75, seed=seed, split="stratified")


def test_dataset_holds_the_run_split_by_gauss_point(run):
    train, heldout = build_dataset(run, 0.75, seed=3)
    assert train.sizes["gp"] == 15 and heldout.sizes["gp"] == 5
    split = split_of(train)
    np.testing.assert_array_equal(split["train"], train.gp.values)
    np.testing.assert_array_equal(split["heldout"], heldout.gp.values)
    np.testing.assert_array_equal(split_of(heldout)["train"], split["train"])
    assert train.attrs["split"] == "train" and heldout.attrs["split"] == "heldout"
    # labelled like a run file; values are those of the run at the same (step, gp)
    assert list(train.comp.values) == list(COMP) and list(train.tcomp.values) == list(TCOMP)
    gp = int(heldout.gp.values[2])
    np.testing.assert_array_equal(heldout.stress.sel(gp=gp).values, run.stress.sel(gp=gp).values)
    np.testing.assert_array_equal(heldout.tangent.sel(gp=gp).values, run.tangent.sel(gp=gp).values)
    np.testing.assert_allclose(heldout.history.sel(gp=gp).values, history_from_sequence(run.strain.sel(gp=gp).values))


def test_features_and_targets_layout(run):
    train, _ = build_dataset(run, 0.75, seed=3)
    x = features(train)
    n_samples = train.sizes["step"] * train.sizes["gp"]
    assert x.shape == (n_samples, 9) and features(train, history=False).shape == (n_samples, 6)
    assert targets(train, "sigma").shape == (n_samples, 6) and targets(train, "tangent").shape == (n_samples, 21)
    # sample (step 7, 4th training point) sits at row 7 * n_gp + 3, columns in FEATURES order
    n_gp = train.sizes["gp"]
    gp = int(train.gp.values[3])
    row = 7 * n_gp + 3
    np.testing.assert_array_equal(x[row, :6], run.strain.sel(step=7, gp=gp).values)
    np.testing.assert_allclose(x[row, 6:], history_from_sequence(run.strain.sel(gp=gp).values)[7, :3])  # φ1–φ3
    with_psi = features(train, history=["psi2", "phi1", "psi1"])  # taken in HIST order: phi1, psi1, psi2
    np.testing.assert_allclose(with_psi[row, 6:], history_from_sequence(run.strain.sel(gp=gp).values)[7, [0, 3, 4]])
    np.testing.assert_array_equal(targets(train, "tangent")[row], run.tangent.sel(step=7, gp=gp).values)
    assert list(train.feature.values) == list(FEATURES)
    assert len(TANGENT_TARGETS) == 21 and STRAIN_FEATURES[3] == "strain_23"


def test_scaling_fitted_on_training_points_only(run):
    train, heldout = build_dataset(run, 0.75, seed=3)
    for ds in (train, heldout):  # both files carry the same (training) scaling
        sc = scaling(ds, "sigma")
        np.testing.assert_array_equal(sc["x_min"], features(train).min(axis=0))
        np.testing.assert_array_equal(sc["x_max"], features(train).max(axis=0))
        np.testing.assert_array_equal(sc["y_min"], targets(train, "sigma").min(axis=0))
    x_scaled = (features(train) - sc["x_min"]) / (sc["x_max"] - sc["x_min"])
    assert x_scaled.min() == 0.0 and x_scaled.max() == 1.0
    # held-out points have their own extremes: some fall outside [0, 1] (else the split was not by point)
    x_ho = (features(heldout) - sc["x_min"]) / (sc["x_max"] - sc["x_min"])
    assert x_ho.min() < 0.0 or x_ho.max() > 1.0
    assert scaling(train, "tangent", history=False)["x_min"].shape == (6,)
    assert scaling(train, "tangent")["y_max"].shape == (21,)


def test_dataset_file_roundtrip(run, tmp_path):
    train, heldout = build_dataset(run, 0.75, seed=3)
    write_dataset(train, tmp_path / "d" / "train.h5")
    back = read_dataset(tmp_path / "d" / "train.h5")
    np.testing.assert_array_equal(back.stress.values, train.stress.values)
    np.testing.assert_array_equal(split_of(back)["heldout"], heldout.gp.values)
    np.testing.assert_array_equal(features(back), features(train))
    assert back.stress.attrs["units"] == "Pa"
    assert not list((tmp_path / "d").glob("*.tmp"))
    with pytest.raises(DatasetError, match="not found"):
        read_dataset(tmp_path / "missing.h5")


def test_bad_runs_are_named(run):
    bad = run.copy(deep=True)
    bad["stress"][5, 3, 2] = np.nan
    with pytest.raises(DatasetError, match=r"'stress' is not finite at step 5, gp 3"):
        build_dataset(bad, 0.75, 0, source="ref.h5")
    with pytest.raises(DatasetError, match="ref.h5: variable 'tangent' missing"):
        build_dataset(run.drop_vars("tangent"), 0.75, 0, source="ref.h5")
    reordered = run.assign_coords(comp=["11", "22", "33", "12", "13", "23"])
    with pytest.raises(DatasetError, match="coordinate 'comp'"):
        build_dataset(reordered, 0.75, 0)
    with pytest.raises(DatasetError, match="dem_points.h5: no trajectories"):
        build_dataset_from_sources([("ref.h5", run), ("dem_points.h5", run.isel(gp=slice(0, 0)))], 0.75, 0)


def test_synthetic_run_is_the_material_response(run):
    # the fixture itself: a fresh elastoplastic point answers the same at step 1
    config = validate_config({"reference_material": "elastoplastic"})
    ep = Elastoplastic.from_config(run.sizes["gp"], config)
    s, D = ep.evaluate(run.strain.sel(step=1).values)
    np.testing.assert_allclose(run.stress.sel(step=1).values, s)
    np.testing.assert_allclose(run.tangent.sel(step=1).values, tangent_to_upper(D))


def _mirror(strain):
    """The strain history of the mirror-image point: x -> -x (ε13, ε12 change sign), then x <-> y."""
    m = strain.copy()
    m[..., 4] *= -1
    m[..., 5] *= -1
    return m[..., [1, 0, 2, 4, 3, 5]]


def test_trajectory_classes_group_mirror_images_and_nothing_else():
    rng = np.random.default_rng(3)
    base = np.cumsum(rng.normal(0, 1e-3, (30, 1, 6)), axis=0)
    other = np.cumsum(rng.normal(0, 1e-3, (30, 1, 6)), axis=0)
    near = base * 1.001  # 0.1 % of the largest strain away: the same history at 2 %
    far = base.copy()
    far[15:, :, 2] += 0.05 * np.abs(base).max()  # 5 % away in ε33 from step 15 on
    strain = np.concatenate([base, _mirror(base), other, near, far, _mirror(other)], axis=1)
    classes = trajectory_classes(strain, 0.02)
    np.testing.assert_array_equal(classes, [0, 0, 1, 0, 2, 1])
    # at a tolerance below the 0.1 % step, `near` is a history of its own; mirrors stay together (round-off)
    np.testing.assert_array_equal(trajectory_classes(strain, 1e-4), [0, 0, 1, 2, 3, 1])


@pytest.mark.parametrize("seed", range(4))
def test_trajectory_split_never_cuts_a_class(seed):
    classes = np.repeat(np.arange(10), [1, 2, 3, 4, 1, 2, 3, 4, 1, 2])  # 23 trajectories
    train, heldout = split_trajectories(classes, 0.75, seed)
    assert not set(classes[train]) & set(classes[heldout])
    np.testing.assert_array_equal(np.sort(np.concatenate([train, heldout])), np.arange(23))
    assert abs(train.size - 0.75 * 23) <= 4  # whole classes of at most 4 trajectories
    # every trajectory its own class: the paper's split by Gauss point, exactly
    for a, b in zip(split_trajectories(np.arange(40), 0.75, seed), split_gauss_points(40, 0.75, seed)):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(DatasetError, match="2 distinct trajectories"):
        split_trajectories(np.zeros(5, dtype=int), 0.75, seed)


def test_sources_of_different_lengths_are_padded_and_masked(run):
    short = run.isel(step=slice(0, 20), gp=slice(0, 6)).assign_attrs(method="rve_paths")
    train, heldout = build_dataset_from_sources([("long", run), ("short", short)], 0.5, seed=1, history_tolerance=1e-6)
    both = xr.concat([train, heldout], dim="gp", data_vars="all")
    assert both.sizes["gp"] == run.sizes["gp"] + 6 and both.sizes["step"] == run.sizes["step"]
    padded = both.isel(gp=both.source.values == "short")
    assert not padded.valid.values[20:].any() and padded.valid.values[:20].all()
    assert np.isnan(padded.stress.values[20:]).all()
    # features/targets hold the valid samples only, and the scaling ignores the padding
    n_valid = int(train.valid.values.sum())
    assert features(train, history=HIST).shape == (n_valid, 6 + len(HIST)) and np.isfinite(targets(train, "sigma")).all()
    assert np.isfinite(train.stress_min.values).all()
    # each source is split on its own: both sides hold trajectories of both
    for side in (train, heldout):
        assert set(side.source.values) == {"long", "short"}
    # the mesh Gauss points of the run source on each side, for the error maps of validation runs
    assert set(train.attrs["train_gp"]) == set(train.source_gp.values[train.source.values == "long"])


def test_a_dataset_without_psi_names_the_rebuild(run):
    """A dataset written before ψ1, ψ2 existed holds φ1–φ3 only: selecting ψ must say so, not KeyError."""
    train, _ = build_dataset(run, 0.75, seed=3)
    old = train.sel(hist=list(PHI), feature=list(STRAIN_FEATURES + PHI))
    assert features(old).shape[1] == 9  # the default φ1–φ3 still reads
    for read in (lambda: features(old, ["phi1", "psi1"]), lambda: scaling(old, "sigma", ["psi2"])):
        with pytest.raises(DatasetError, match=r"no history variables \['psi.'\].*rebuild"):
            read()
