"""Small synthetic runs in the data contract (DESIGN.md §5), for the analysis tests.

They follow the contract to the letter (coordinates, labels, units, signs, the skfem hex
mesh with gp = element*8 + q) and have the shapes of real runs: a hysteretic deviatoric
response that loops on unloading, a 'surrogate' close to it, and a 'no-history' surrogate
that goes back down its loading curve on unloading (no loop).
"""

from __future__ import annotations

import numpy as np
import xarray as xr
import yaml
from skfem import Basis, ElementHex1, MeshHex

from granular_multiscale.history import HIST, history_from_sequence
from granular_multiscale.paths import LoadPath
from granular_multiscale.tensors import COMP, TCOMP, isotropic_elastic_tangent, tangent_to_upper

PATH2 = LoadPath("path2", ((9, 0.009), (6, 0.003), (42, 0.045)))
P0 = 100e3


def mesh_and_gauss_points(size=(0.5, 0.5, 1.0), elements=(1, 1, 2)):
    mesh = MeshHex.init_tensor(*(np.linspace(0.0, s, n + 1) for s, n in zip(size, elements)))
    basis = Basis(mesh, ElementHex1(), intorder=3)
    gp = basis.mapping.F(basis.X)  # [3, n_elements, 8]
    return mesh, np.transpose(gp, (1, 2, 0)).reshape(-1, 3)


def _deviatoric_response(strain_axial: np.ndarray, history: bool) -> np.ndarray:
    """q over the steps: hyperbolic backbone on loading, stiff elastic unloading (a loop)."""
    e0, q_max = 4e7, 250e3
    q = np.zeros_like(strain_axial)
    for k in range(1, len(strain_axial)):
        d = strain_axial[k] - strain_axial[k - 1]
        if not history:
            q[k] = q_max * strain_axial[k] / (q_max / e0 + strain_axial[k])
            continue
        stiffness = e0 * max(1.0 - q[k - 1] / q_max, 0.02) ** 2 if d > 0 else e0
        q[k] = min(q[k - 1] + stiffness * d, 0.999 * q_max)
    return q


def make_run(kind: str = "reference", path: LoadPath = PATH2, size=(0.5, 0.5, 1.0), elements=(1, 1, 2),
             seed: int = 0, wall_per_step: float = 1.0) -> xr.Dataset:
    rng = np.random.default_rng(seed)
    mesh, gp_position = mesh_and_gauss_points(size, elements)
    n_gp, n_node = len(gp_position), mesh.p.shape[1]
    ea = path.axial_strain()
    n_step = len(ea)
    height = size[2]
    # spatial variation: more strain near mid-height, a little shear in the 23 plane
    z = gp_position[:, 2] / height
    y = gp_position[:, 1] / size[1]
    weight = 1.0 + 0.3 * np.sin(np.pi * z)
    strain = np.zeros((n_step, n_gp, 6))
    strain[:, :, 2] = -ea[:, None] * weight
    strain[:, :, 0] = strain[:, :, 1] = 0.35 * ea[:, None] * weight
    strain[:, :, 3] = 0.05 * ea[:, None] * np.sin(2 * np.pi * z) * (y - 0.5)
    q = np.stack([_deviatoric_response(-strain[:, g, 2], history=(kind != "nohist")) for g in range(n_gp)], axis=1)
    stress = np.zeros((n_step, n_gp, 6))
    stress[:, :, 0] = stress[:, :, 1] = -P0
    stress[:, :, 2] = -P0 - q
    stress[:, :, 3] = 2 * 1.5e7 * strain[:, :, 3]
    if kind != "reference":
        noise = 0.02 if kind == "ml" else 0.04
        # the initial (consolidated) state is the same for every method
        stress[1:] = stress[1:] * (1.0 + noise * rng.standard_normal(stress[1:].shape))
    tangent = np.broadcast_to(tangent_to_upper(isotropic_elastic_tangent(5e7, 0.25)), (n_step, n_gp, 21)).copy()
    nodes = mesh.p.T
    displacement = np.zeros((n_step, n_node, 3))
    bulge = np.sin(np.pi * nodes[:, 2] / height)
    displacement[:, :, 2] = -ea[:, None] * nodes[None, :, 2]
    displacement[:, :, 0] = 0.35 * ea[:, None] * (nodes[None, :, 0] - size[0] / 2) * (1 + 0.5 * bulge)
    displacement[:, :, 1] = 0.35 * ea[:, None] * (nodes[None, :, 1] - size[1] / 2) * (1 + 0.5 * bulge)
    top = gp_position[:, 2] > gp_position[:, 2].max() - 1e-9
    area = size[0] * size[1]
    top_force = stress[:, top, 2].mean(axis=1) * area
    ds = xr.Dataset(
        {
            "strain": (("step", "gp", "comp"), strain, {"units": "1", "long_name": "strain (tensorial shear)"}),
            "stress": (("step", "gp", "comp"), stress, {"units": "Pa", "long_name": "stress, tension positive"}),
            "tangent": (("step", "gp", "tcomp"), tangent, {"units": "Pa"}),
            "history": (("step", "gp", "hist"), history_from_sequence(strain), {"units": "1"}),
            "gp_position": (("gp", "xyz"), gp_position, {"units": "m"}),
            "node_position": (("node", "xyz"), nodes, {"units": "m"}),
            "displacement": (("step", "node", "xyz"), displacement, {"units": "m"}),
            "axial_strain": (("step",), ea, {"units": "1"}),
            "top_force": (("step",), top_force, {"units": "N"}),
            "load_force": (("step",), -top_force, {"units": "N"}),
            "load_displacement": (("step",), ea * height, {"units": "m"}),
            "volumetric_strain": (("step",), strain[:, :, :3].sum(axis=2).mean(axis=1), {"units": "1"}),
            "newton_iterations": (("step",), np.r_[0, rng.integers(2, 6, n_step - 1)]),
            "wall_time": (("step",), np.r_[0.0, np.full(n_step - 1, wall_per_step)], {"units": "s"}),
            "phase": (("step",), path.phase()),
        },
        coords={
            "step": np.arange(n_step),
            "gp": np.arange(n_gp),
            "comp": list(COMP),
            "tcomp": list(TCOMP),
            "hist": list(HIST),
            "node": np.arange(n_node),
            "xyz": ["x", "y", "z"],
        },
        attrs={
            "method": {"reference": "elastoplastic", "ml": "fem_ml_nn", "nohist": "fem_ml_nn_nohist"}[kind],
            "config": yaml.safe_dump({"specimen": {"size": list(size), "elements": list(elements)}}),
        },
    )
    return ds


def split_gauss_points(n_gp: int, seed: int = 0, train_fraction: float = 0.75):
    order = np.random.default_rng(seed).permutation(n_gp)
    n_train = int(round(train_fraction * n_gp))
    return np.sort(order[:n_train]), np.sort(order[n_train:])


# --------------------------------------------------------------------------------------
# real tiny runs with the project's FEM solver, standing in for every input of the analysis
# rules (the surrogate stage's outputs are imitated by other analytic materials)


def solve(config: dict, material: str, path_name: str, overrides: dict | None = None):
    """One triaxial run with an analytic material; ``overrides`` edit that material's section."""
    import copy

    from granular_multiscale.config import validate_config
    from granular_multiscale.fem.triaxial import TriaxialProblem
    from granular_multiscale.materials import make_material
    from granular_multiscale.paths import load_paths_from_config

    config = copy.deepcopy(config)
    config.setdefault(material, {}).update(overrides or {})
    config = validate_config(config)
    problem = TriaxialProblem.from_config(config)
    with make_material(material, problem.n_gauss_points, config) as points:
        return problem.run(points, load_paths_from_config(config)[path_name], progress=False), config


def write_analysis_inputs(out_dir, config: dict) -> dict:
    """Every file the analysis rules read, for the validation path, where the plan's layout
    under ``out_dir`` puts it.

    reference = the elastoplastic model; 'FEM–ML' = the same model with 5 % stiffer elasticity
    and 5 % less hardening (a close imitation); 'no history' = linear elasticity (no loop);
    dataset split, and loss curves of the shape the training stage writes."""
    from pathlib import Path

    import pandas as pd

    from granular_multiscale.data import write_run
    from granular_multiscale.plan import Layout

    layout = Layout(out_dir)
    path = config["validation_path"]
    reference, cfg = solve(config, "elastoplastic", path)
    write_run(reference, layout.run("fem_elastoplastic", path), cfg)
    E = cfg["elastoplastic"]["youngs_modulus"]
    close, _ = solve(config, "elastoplastic", path, {
        "youngs_modulus": 1.05 * E,
        "saturated_hardening": 0.95 * cfg["elastoplastic"]["saturated_hardening"],
    })
    close.attrs["method"] = "fem_ml_nn"
    write_run(close, layout.fem_ml(path), cfg)
    elastic, _ = solve(config, "linear_elastic", path, {"youngs_modulus": 0.3 * E})
    elastic.attrs["method"] = "fem_ml_nn_nohist"
    write_run(elastic, layout.run("fem_ml_nohist", path), cfg)
    train_gp, heldout_gp = split_gauss_points(reference.sizes["gp"], seed=cfg["seed"])
    for name, ids in (("train", train_gp), ("heldout", heldout_gp)):
        subset = reference[["strain", "stress", "gp_position"]].sel(gp=ids)
        Path(layout.dataset(name)).parent.mkdir(parents=True, exist_ok=True)
        subset.to_netcdf(layout.dataset(name), engine="h5netcdf")
    epochs = np.arange(1, 31)
    for name, level in (("sigma", 0.02), ("tangent", 0.04), ("sigma_nohist", 0.05), ("tangent_nohist", 0.07)):
        curve = Path(layout.training(f"{name}.csv"))
        curve.parent.mkdir(parents=True, exist_ok=True)
        pd.DataFrame({
            "epoch": epochs,
            "train_loss": level * (1 + 5 / epochs),
            "heldout_loss": 1.1 * level * (1 + 5 / epochs),
            "elapsed_s": 0.01 * epochs,
        }).to_csv(curve, index=False)
    return {"reference": reference, "train_gp": train_gp, "heldout_gp": heldout_gp}
