"""Data contract: write/read round trip, names and attributes, damaged files."""

import h5py
import numpy as np
import pytest

from granular_multiscale.config import validate_config
from granular_multiscale.data import (REQUIRED_VARIABLES, DataFileError, read_run, run_config, run_tangent,
                                     tangent_variables, write_run)
from granular_multiscale.fem.triaxial import TriaxialProblem
from granular_multiscale.history import HIST, history_from_sequence
from granular_multiscale.materials import make_material
from granular_multiscale.paths import load_paths_from_config
from granular_multiscale.tensors import (COMP, SYMMETRY_RTOL, TCOMP, TCOMP36, isotropic_elastic_tangent, symmetric_part,
                                        tangent_asymmetry, tangent_from_full, tangent_from_upper,
                                        tangent_to_full, tangent_to_upper)


@pytest.fixture(scope="module")
def run():
    config = validate_config({"specimen": {"elements": [1, 1, 2]}, "reference_material": "elastoplastic"})
    problem = TriaxialProblem.from_config(config)
    path = load_paths_from_config(config)["path2"]
    ds = problem.run(make_material("elastoplastic", problem.n_gauss_points, config), path, progress=False)
    return config, ds


def test_round_trip_keeps_every_value_and_label(run, tmp_path):
    config, ds = run
    path = write_run(ds, tmp_path / "fem_elastoplastic" / "path2.h5", config)
    back = read_run(path)
    for name in ds.variables:
        np.testing.assert_array_equal(back[name].values, ds[name].values, err_msg=name)
    assert list(back.comp.values) == list(COMP)
    assert list(back.tcomp.values) == list(TCOMP)
    assert list(back.hist.values) == list(HIST)
    assert back.sizes == {"step": 58, "gp": 16, "comp": 6, "tcomp": 21, "hist": 5, "node": 12, "xyz": 3,
                          "iteration": ds.sizes["iteration"], "element": 2, "vertex": 8}
    assert back.attrs["method"] == "elastoplastic"
    assert back.stress.attrs["units"] == "Pa" and back.top_force.attrs["units"] == "N"
    assert run_config(back) == config
    assert list(back.phase.values[[0, 1, 10, 16]]) == ["initial", "loading", "unloading", "reloading"]
    # a symmetric tangent (elastoplastic, DEM) keeps the 21-entry layout, labelled as complete
    assert "tangent_full" not in back and "tcomp36" not in back.coords
    assert back.attrs["tangent_symmetric"] == 1 and back.attrs["tangent_variable"] == "tangent"
    assert back.attrs["tangent_asymmetry"] <= 1e-10
    np.testing.assert_array_equal(run_tangent(back), tangent_from_upper(back.tangent.values))


def test_contract_contents_are_consistent(run):
    _, ds = run
    assert set(REQUIRED_VARIABLES) <= set(ds.variables)
    np.testing.assert_allclose(ds.history.values, history_from_sequence(ds.strain.values))
    # step 0 is the consolidated state: no strain, isotropic −p0, top force −p0·A
    np.testing.assert_allclose(ds.stress.values[0], np.tile([-1e5, -1e5, -1e5, 0, 0, 0], (16, 1)), atol=1e-6)
    assert ds.top_force.values[0] == pytest.approx(-1e5 * 0.25)
    # stored tangent: the symmetric consistent tangent of the converged state
    D = tangent_from_upper(ds.tangent.values[20])
    material = make_material("elastoplastic", 16, validate_config({}))
    for k in range(21):  # replay the converged strains point-wise
        stress, tangent = material.evaluate(ds.strain.values[k])
        material.commit()
    np.testing.assert_allclose(D, tangent, rtol=1e-9, atol=1e-3)
    np.testing.assert_allclose(stress, ds.stress.values[20], atol=1e-6)


def test_readable_by_h5py(run, tmp_path):
    config, ds = run
    path = write_run(ds, tmp_path / "run.h5", config)
    with h5py.File(path, "r") as f:
        assert f["stress"].shape == (58, 16, 6)
        assert f["axial_strain"][-1] == pytest.approx(0.045)


def test_missing_file_names_the_file(tmp_path):
    with pytest.raises(DataFileError, match=r"nothere\.h5 does not exist"):
        read_run(tmp_path / "nothere.h5")


def test_truncated_file_names_the_file(run, tmp_path):
    config, ds = run
    path = write_run(ds, tmp_path / "cut.h5", config)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(DataFileError, match=r"run file .*cut\.h5 is corrupt: its sha256 .* differs from"):
        read_run(path)
    (tmp_path / "cut.h5.sha256").unlink()  # without its checksum: HDF5's own error, with the name
    with pytest.raises(DataFileError, match=r"cut\.h5 is not a readable"):
        read_run(path)


def test_corrupt_file_names_the_file(tmp_path):
    path = tmp_path / "garbage.h5"
    path.write_bytes(b"this is not an HDF5 file" * 100)
    with pytest.raises(DataFileError, match=r"garbage\.h5"):
        read_run(path)


def test_missing_variable_names_variable_and_file(run, tmp_path):
    _, ds = run
    path = tmp_path / "partial.h5"
    ds.drop_vars("tangent").to_netcdf(path, engine="h5netcdf", invalid_netcdf=True)
    with pytest.raises(DataFileError, match=r"partial\.h5 lacks variables \['tangent'\]"):
        read_run(path)


def test_write_is_atomic_and_refuses_incomplete_runs(run, tmp_path):
    _, ds = run
    target = tmp_path / "run.h5"
    with pytest.raises(ValueError, match="lacks variables"):
        write_run(ds.drop_vars("stress"), target)
    assert not target.exists()
    assert list(tmp_path.iterdir()) == []  # no temporary left behind
    bad = ds.copy()
    bad.attrs["unserialisable"] = {"a": object()}  # fails inside to_netcdf
    with pytest.raises(Exception):
        write_run(bad, target)
    assert list(tmp_path.iterdir()) == []


def test_non_finite_stress_is_reported(run, tmp_path):
    _, ds = run
    bad = ds.copy(deep=True)
    bad["stress"].values[3, 2, 1] = np.nan
    path = tmp_path / "nan.h5"
    bad.to_netcdf(path, engine="h5netcdf", invalid_netcdf=True)
    with pytest.raises(DataFileError, match=r"nan\.h5: variable 'stress' holds non-finite values"):
        read_run(path)


def test_full_tangent_helpers_round_trip():
    rng = np.random.default_rng(3)
    D = rng.normal(size=(2, 3, 6, 6))
    np.testing.assert_array_equal(tangent_from_full(tangent_to_full(D)), D)
    assert [TCOMP36[6 * I + J] for I, J in ((0, 0), (0, 2), (2, 0), (5, 4))] == ["1111", "1133", "3311", "1213"]
    assert set(TCOMP) <= set(TCOMP36) and len(set(TCOMP36)) == 36
    sym = symmetric_part(D)
    np.testing.assert_array_equal(sym, np.swapaxes(sym, -1, -2))
    E = isotropic_elastic_tangent(5e7, 0.3)
    assert tangent_asymmetry(E) == 0.0 and tangent_asymmetry(E) <= SYMMETRY_RTOL and tangent_asymmetry(np.zeros((6, 6))) == 0.0
    E[0, 1] *= 1 + 1e-14  # round-off: still symmetric
    assert tangent_asymmetry(E) <= SYMMETRY_RTOL
    E[0, 1] *= 1 + 1e-6
    assert not tangent_asymmetry(E) <= SYMMETRY_RTOL and tangent_asymmetry(E) == pytest.approx(1e-6 * E[0, 1] / E.max(), rel=1e-6)


def test_tangent_variables_take_older_checkpoint_records():
    """A run resumed from a checkpoint written before the run file kept the full tangent holds 21-entry records for its first steps."""
    D = isotropic_elastic_tangent(5e7, 0.3) + np.diag([0, 0, 0, 0, 0, 1e5])
    skew = D.copy()
    skew[0, 3] += 2e5
    old = np.broadcast_to(tangent_to_upper(D), (4, 21))
    variables, attrs = tangent_variables([old, np.broadcast_to(skew, (4, 6, 6))])
    assert attrs["tangent_symmetric"] == 0
    dims, values, units, _ = variables["tangent_full"]
    assert dims == ("step", "gp", "tcomp36") and units == "Pa"
    np.testing.assert_array_equal(tangent_from_full(values), np.stack([np.broadcast_to(m, (4, 6, 6)) for m in (D, skew)]))
    np.testing.assert_array_equal(variables["tangent"][1][1], np.broadcast_to(tangent_to_upper(symmetric_part(skew)), (4, 21)))


def test_run_tangent_reads_files_without_tangent_full(run, tmp_path):
    """Files written before tangent_full existed (no tangent_* attrs) still give their 6×6 tangents."""
    config, ds = run
    old = ds.copy()
    for key in ("tangent_symmetric", "tangent_asymmetry", "tangent_variable"):
        old.attrs.pop(key, None)
    back = read_run(write_run(old, tmp_path / "old.h5", config))
    np.testing.assert_array_equal(run_tangent(back), tangent_from_upper(ds.tangent.values))
