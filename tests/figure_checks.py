"""What each figure of the report must show, computed here from the run files and tables the
figure was drawn from, and the checks that the numbers a figure function returns (the numbers
it drew, see granular_multiscale.analysis.figures) are those.

The expected values are written out here from the data contract (stress in Pa, tension positive,
Voigt order 11 22 33 23 13 12 with tensorial shear strains, gp = element*8 + q), not through the
package's functions, so that a figure of the wrong run, Gauss point, component, step or split
fails."""

from __future__ import annotations

import numpy as np
import pandas as pd
from PIL import Image

# in the norm of a symmetric tensor in Voigt order, each shear component counts twice
SHEAR_TWICE = np.array([1.0, 1.0, 1.0, 2.0, 2.0, 2.0])


def check_png(path, size_in, dpi) -> None:
    """The PNG was written, decodes, and has the size (inches × dpi) the settings ask for."""
    width_in, height_in = size_in
    with Image.open(path) as image:
        image.load()
        assert image.size == (round(width_in * dpi), round(height_in * dpi)), path


def assert_same(actual, expected, what: str) -> None:
    """Equal to the last bit: the same arithmetic on the same numbers (measured: no difference at all
    on the runs of test_analysis_figures.py and of the tiny workflow with either reference)."""
    np.testing.assert_array_equal(np.asarray(actual, dtype=float), np.asarray(expected, dtype=float), err_msg=what)


def assert_curve(drawn, x, y, what: str) -> None:
    assert_same(drawn[0], x, f"{what}: x")
    assert_same(drawn[1], y, f"{what}: y")


def _voigt(ds, name: str) -> np.ndarray:
    """[step, gp, 6] in the order 11, 22, 33, 23, 13, 12."""
    return ds[name].transpose("step", "gp", "comp").sel(comp=["11", "22", "33", "23", "13", "12"]).values


def _deviator(v: np.ndarray) -> np.ndarray:
    d = v.copy()
    d[..., :3] -= v[..., :3].mean(axis=-1, keepdims=True)
    return d


def _contract(v: np.ndarray) -> np.ndarray:
    """t:t of symmetric tensors in Voigt order, [..., 6] -> [...]."""
    return np.sum(SHEAR_TWICE * v**2, axis=-1)


def error_kpa(reference, surrogate) -> np.ndarray:
    """[gp] mean |σ_ML − σ_ref| over the surrogate run's steps, then over the six components, kPa."""
    n = surrogate.sizes["step"]
    return 1e-3 * np.abs(_voigt(surrogate, "stress") - _voigt(reference, "stress")[:n]).mean(axis=0).mean(axis=1)


def check_error_map(drawn: pd.DataFrame, reference, surrogate, train_gp, heldout_gp) -> None:
    """Every training and every held-out point, each in its group, at its position, coloured by
    its own error."""
    for group, ids in (("training", train_gp), ("held out", heldout_gp)):
        rows = drawn[drawn["group"] == group]
        assert sorted(rows["gp"]) == sorted(np.asarray(ids).tolist()), group
        position = reference["gp_position"].transpose("gp", "xyz").values
        assert_same(rows[["x", "y", "z"]], position[rows["gp"]], f"{group}: positions")
        assert_same(rows["error_kpa"], error_kpa(reference, surrogate)[rows["gp"]], f"{group}: errors")
    assert len(drawn) == len(train_gp) + len(heldout_gp)


def check_stress_strain(drawn: dict, runs: dict, gp: int) -> None:
    """Per run, q (kPa, + when σ33 is the most compressive) and tr ε (%) against −ε33 (%) at ``gp``."""
    assert list(drawn["q_kpa"]) == list(drawn["volumetric_strain_pct"]) == list(runs)
    for label, ds in runs.items():
        strain, stress = _voigt(ds, "strain")[:, gp], _voigt(ds, "stress")[:, gp]
        sign = np.where(0.5 * (stress[:, 0] + stress[:, 1]) >= stress[:, 2], 1.0, -1.0)
        q = sign * np.sqrt(1.5 * _contract(_deviator(stress)))  # sqrt(3 J2), J2 = s:s / 2
        axial = -100 * strain[:, 2]
        assert_curve(drawn["q_kpa"][label], axial, 1e-3 * q, f"q of {label} at gp {gp}")
        assert_curve(drawn["volumetric_strain_pct"][label], axial, 100 * strain[:, :3].sum(axis=1),
                     f"volumetric strain of {label} at gp {gp}")


def check_global_response(drawn: dict, runs: dict) -> None:
    """Per run, the top force (kN, compression +) and the specimen's volumetric strain (%) per step."""
    assert list(drawn["top_force_kn"]) == list(drawn["volumetric_strain_pct"]) == list(runs)
    for label, ds in runs.items():
        steps = np.arange(ds.sizes["step"])
        assert_curve(drawn["top_force_kn"][label], steps, -1e-3 * ds["top_force"].values, f"top force of {label}")
        assert_curve(drawn["volumetric_strain_pct"][label], steps, 100 * ds["volumetric_strain"].values,
                     f"volumetric strain of {label}")


def field_values(ds, quantity: str, step: int) -> np.ndarray:
    """u_z at the nodes (mm); ε_s (%) or σ23 (kPa) averaged over each element's 8 Gauss points."""
    if quantity == "axial_displacement":
        return 1e3 * ds["displacement"].sel(step=step, xyz="z").values
    if quantity == "sigma23":
        per_gp = 1e-3 * _voigt(ds, "stress")[step, :, 3]
    else:
        per_gp = 100 * np.sqrt(2 / 3 * _contract(_deviator(_voigt(ds, "strain")[step])))  # sqrt(2/3 e:e)
    return per_gp.reshape(-1, 8).mean(axis=1)


def check_fields(drawn: dict, reference, surrogate, quantity: str, steps) -> None:
    """Each row a step: the reference's field, the surrogate's and their difference (the reference
    alone at a step the surrogate did not reach)."""
    assert list(drawn) == list(steps)
    for step in steps:
        ref = field_values(reference, quantity, step)
        assert_same(drawn[step]["reference"], ref, f"{quantity}, step {step}: reference")
        if step >= surrogate.sizes["step"]:
            assert set(drawn[step]) == {"reference"}
            continue
        ml = field_values(surrogate, quantity, step)
        assert_same(drawn[step]["surrogate"], ml, f"{quantity}, step {step}: surrogate")
        assert_same(drawn[step]["difference"], ml - ref, f"{quantity}, step {step}: difference")


def check_training_curves(drawn: dict, curve_files: dict) -> None:
    """Per 'panel|series' loss table: its training and held-out loss per epoch, in its panel; an
    ensemble's table (a column member) a pair of curves per member, labelled with their count."""
    pairs = 0
    for key, path in curve_files.items():
        panel, _, series = key.partition("|")
        table = pd.read_csv(path)
        members = list(table.groupby("member")) if "member" in table else [(None, table)]
        if len(members) > 1:
            series = f"{series}, {len(members)} members" if series else f"{len(members)} members"
        for member, rows in members:
            for line, column in (("training", "train_loss"), ("held out", "heldout_loss")):
                name = f"{line} ({series})" if series else line
                name += "" if len(members) == 1 else f", member {member}"
                assert_curve(drawn[panel][name], rows["epoch"], rows[column], f"{key} {name}")
            pairs += 1
    assert sum(len(curves) for curves in drawn.values()) == 2 * pairs


def check_speed_vs_error(drawn: dict, speedup_csv, accuracy_csv) -> None:
    """Per error measure, each run of this machine at (its error, its wall time); the reference
    (the speedup table's first row) at error 0."""
    speed = pd.read_csv(speedup_csv)
    speed = speed[speed["source"] == "this run"].set_index("method")
    accuracy = pd.read_csv(accuracy_csv).set_index("method")
    reference = speed.index[0]
    assert list(drawn) == ["stress_mae_all_kpa", "top_force_max_rel_pct"]
    for column, points in drawn.items():
        points = {label: point for label, point in points.items() if label != "curve"}
        assert len(points) == len(speed)
        for method, row in speed.iterrows():
            stopped = [label for label in points if label.startswith(f"{method} (stopped after step")]
            label = method if row["completed"] == "yes" else stopped[0]
            error = 0.0 if method == reference else accuracy.loc[method, column]
            assert points[label] == (error, row["wall_time_s"]), (column, method)


def check_calibration(drawn: dict, run, reference) -> None:
    """Per load step >= 1, the median and 90th percentile over the Gauss points of the error
    ‖σ_ML − σ_ref‖ (kPa, the tensor's norm) and, with an ensemble, of the spread; with an
    ensemble, every (step, point) pair of positive spread and error at (spread, error)."""
    n = run.sizes["step"]
    error = 1e-3 * np.sqrt(_contract(_voigt(run, "stress") - _voigt(reference, "stress")[:n]))[1:]
    spread = 1e-3 * np.sqrt(_contract(_voigt(run, "stress_spread")))[1:]
    expected = {"error, median": np.median(error, axis=1), "error, 90th percentile": np.percentile(error, 90, axis=1)}
    if spread.any():  # an ensemble of several networks
        expected.update({"spread, median": np.median(spread, axis=1),
                         "spread, 90th percentile": np.percentile(spread, 90, axis=1)})
        pair = (spread > 0) & (error > 0)
        assert_curve(drawn["error_vs_spread"]["pairs"], spread[pair], error[pair], "(spread, error) pairs")
    else:
        assert drawn["error_vs_spread"] == {}
    assert list(drawn["per_step"]) == list(expected)
    for label, values in expected.items():
        assert_curve(drawn["per_step"][label], run["step"].values[1:], values, label)
