"""NNσ/ND training: seeded and deterministic, learns, self-sufficient model files, loss/MAE outputs."""

import numpy as np
import pytest
import torch
from PIL import Image

from granular_multiscale.analysis.figures import plot_losses
from granular_multiscale.config import CONFIG_DIR, load_config, validate_config
from granular_multiscale.materials.elastoplastic import Elastoplastic
from granular_multiscale.paths import load_paths_from_config
from granular_multiscale.surrogate.dataset import STRAIN_FEATURES, TANGENT_TARGETS, build_dataset, features, targets
from granular_multiscale.surrogate.models import EnsembleMLP, ModelFileError, SurrogateModel
from granular_multiscale.surrogate import training
from granular_multiscale.surrogate.training import TrainingError, model_seed, train

CONFIG = validate_config({"reference_material": "elastoplastic"})
FAST = dict(CONFIG["surrogate"], epochs=6, learning_rate=3e-3, log_every=2)


@pytest.fixture(scope="module")
def data():
    from granular_multiscale.surrogate.synthetic import material_point_run, triaxial_strain_paths

    path = load_paths_from_config(CONFIG)["path1"]
    run = material_point_run(Elastoplastic.from_config(16, CONFIG), triaxial_strain_paths(path, 16, seed=1), path)
    return build_dataset(run, 0.75, seed=0)


def test_paper_defaults_in_config():
    """The schema defaults are the paper's Table 3; config/paper.yaml adds its ND tangent."""
    for s in (CONFIG["surrogate"], load_config(CONFIG_DIR / "paper.yaml")["surrogate"]):
        assert (s["hidden_layers"], s["hidden_units"], s["batch_size"], s["learning_rate"], s["epochs"], s["loss"]) == (
            4, 20, 64, 1e-4, 600, "mae"
        )
        assert s["train_fraction"] == 0.75 and s["history_variables"] == ["phi1", "phi2", "phi3"]
        assert s["lr_schedule"] == "constant" and s["jacobian_loss_weight"] == 0.0
    assert load_config(CONFIG_DIR / "paper.yaml")["surrogate"]["tangent"] == "nn"


def test_architecture_follows_config(data):
    model = SurrogateModel.create("tangent", True, {k: np.zeros(n) for k, n in
                                                     (("x_min", 9), ("x_max", 9), ("y_min", 21), ("y_max", 21))},
                                  dict(FAST, hidden_layers=3, hidden_units=7, activation="relu"))
    linears = [m for m in model.network.net if isinstance(m, torch.nn.Linear)]
    assert [(m.in_features, m.out_features) for m in linears] == [(9, 7), (7, 7), (7, 7), (7, 21)]
    assert sum(isinstance(m, torch.nn.ReLU) for m in model.network.net) == 3
    assert model.target_names == TANGENT_TARGETS and model.feature_names == STRAIN_FEATURES + ("phi1", "phi2", "phi3")


def test_training_is_deterministic_and_seeded(data):
    a, loss_a, _ = train(*data, "sigma", FAST, seed=5)
    b, loss_b, _ = train(*data, "sigma", FAST, seed=5)
    c, _, _ = train(*data, "sigma", FAST, seed=6)
    for (name, pa), pb in zip(a.network.state_dict().items(), b.network.state_dict().values()):
        assert torch.equal(pa, pb), name
    np.testing.assert_array_equal(loss_a[["train_loss", "heldout_loss"]].values, loss_b[["train_loss", "heldout_loss"]].values)
    assert not torch.equal(a.network.net[0].weight, c.network.net[0].weight)
    assert len({model_seed(0, k, h) for k in ("sigma", "tangent") for h in (True, False)}) == 4


def test_history_variables_are_selectable(data):
    settings = dict(FAST, epochs=2, history_variables=["phi2", "phi1"])
    model, _, _ = train(*data, "sigma", settings, seed=0)
    assert model.feature_names == STRAIN_FEATURES + ("phi1", "phi2") and model.history == ("phi1", "phi2")
    x = features(data[1], history=("phi1", "phi2"))
    np.testing.assert_array_equal(x[:, 6:], features(data[1])[:, 6:8])
    assert train(*data, "sigma", settings, seed=0, use_history=False)[0].feature_names == STRAIN_FEATURES
    with pytest.raises(ValueError, match="surrogate.history_variables"):
        train(*data, "sigma", dict(settings, history_variables=["phi4"]), seed=0)


def test_running_maxima_train_and_replay_like_the_dataset(data, tmp_path):
    """ψ1, ψ2 selected (with the Jacobian loss, which differentiates through them): the saved model
    takes them, and a SurrogateMaterial replaying a held-out trajectory's strains computes the same
    features the dataset holds (one definition, history.py), so it predicts what the model predicts."""
    from granular_multiscale.surrogate.material import SurrogateMaterial

    chosen = ("phi1", "phi2", "psi1", "psi2")
    settings = dict(FAST, epochs=2, history_variables=list(reversed(chosen)), jacobian_loss_weight=1.0)
    model, losses, _ = train(*data, "sigma", settings, seed=0)
    assert model.history == chosen and np.isfinite(losses.train_loss).all()
    model.save(tmp_path / "s.pt")
    back = SurrogateModel.load(tmp_path / "s.pt")
    assert back.feature_names == STRAIN_FEATURES + chosen
    # the model keeps its training inputs (all of them: fewer than it keeps) for the distance to them
    np.testing.assert_array_equal(back.training_states, features(data[0], chosen))
    heldout = data[1]
    strain = heldout.strain.transpose("step", "gp", "comp").values
    assert np.all(strain[0] == 0.0)  # the material's fresh state is the dataset's step 0
    x = features(heldout, chosen).reshape(strain.shape[0], strain.shape[1], -1)
    mat = SurrogateMaterial(strain.shape[1], back, tangent="autodiff", anchor_initial_state=False)
    for k in range(strain.shape[0]):
        stress, D = mat.evaluate(strain[k])
        mat.commit()
        np.testing.assert_allclose(mat.history[:, 3:], heldout.history.sel(hist=["psi1", "psi2"]).values[k], rtol=1e-14)
        np.testing.assert_allclose(stress, back.predict(x[k]), rtol=1e-10, atol=1e-6, err_msg=f"step {k}")
        assert np.isfinite(D).all()
    # unloading happens on this path: ψ1 is above the current strain norm somewhere
    norms = np.sqrt(np.sum(np.array([1.0, 1, 1, 2, 2, 2]) * strain**2, axis=-1))
    assert (heldout.history.sel(hist="psi1").values > norms * (1 + 1e-6)).any()


def test_jacobian_loss_teaches_the_tangent(data):
    """With the Jacobian term, NNσ's autodiff tangent moves towards the reference tangent."""
    from granular_multiscale.surrogate.material import SurrogateMaterial

    errors = []
    for weight in (0.0, 1.0):
        model, losses, _ = train(*data, "sigma", dict(FAST, epochs=40, jacobian_loss_weight=weight), seed=0)
        assert np.isfinite(losses.train_loss).all()
        heldout = data[1]
        step = 30
        mat = SurrogateMaterial(heldout.sizes["gp"], model, tangent="autodiff")
        strain = heldout.strain.values
        from granular_multiscale.history import accumulated_from_sequence

        mat.set_state({"strain": strain[step - 1], "accumulated": accumulated_from_sequence(strain)[step - 1]})
        _, D = mat.evaluate(strain[step])
        from granular_multiscale.tensors import tangent_from_upper

        D_ref = tangent_from_upper(heldout.tangent.values[step])
        errors.append(np.abs(D - D_ref).mean() / np.abs(D_ref).mean())
    assert errors[1] < 0.5 * errors[0], errors


def test_training_learns_and_reports(data):
    model, losses, mae = train(*data, "sigma", dict(FAST, epochs=30), seed=0)
    assert list(losses.columns) == ["epoch", "train_loss", "heldout_loss", "elapsed_s", "member"]
    assert list(losses.epoch) == list(range(1, 31))
    assert losses.train_loss.iloc[-1] < 0.4 * losses.train_loss.iloc[0]
    assert losses.heldout_loss.iloc[-1] < 0.4 * losses.heldout_loss.iloc[0]
    # the table's MAE is that of the model's physical-unit predictions
    train_ds, heldout_ds = data
    ho_mae = np.mean(np.abs(model.predict(features(heldout_ds)) - targets(heldout_ds, "sigma")), axis=0)
    np.testing.assert_allclose(mae.heldout_mae_pa.values, ho_mae, rtol=1e-10)
    assert list(mae.target) == [f"stress_{c}" for c in ("11", "22", "33", "23", "13", "12")]
    # better than predicting the mean of the training targets; much better on the loaded σ33
    baseline = np.mean(np.abs(targets(heldout_ds, "sigma") - targets(train_ds, "sigma").mean(axis=0)), axis=0)
    assert np.all(mae.heldout_mae_pa.values[:3] < baseline[:3])
    assert mae.heldout_mae_pa.values[2] < 0.25 * baseline[2]


def test_model_file_is_self_sufficient(data, tmp_path):
    model, _, _ = train(*data, "tangent", FAST, seed=1, use_history=False, config={"surrogate": FAST, "seed": 1})
    model.save(tmp_path / "nd.pt")
    back = SurrogateModel.load(tmp_path / "nd.pt")
    assert back.kind == "tangent" and back.feature_names == STRAIN_FEATURES and not back.use_history
    assert back.target_names == TANGENT_TARGETS
    assert back.config["surrogate"]["epochs"] == FAST["epochs"] and back.training["epochs"] == FAST["epochs"]
    np.testing.assert_array_equal(back.training["heldout_gp"], data[1].gp.values)
    x = features(data[1], history=False)
    # float64 reload of float32 weights: same predictions to float32 accuracy, scaling kept in float64
    np.testing.assert_allclose(back.predict(x), model.predict(x), rtol=1e-4, atol=1e-3 * np.abs(model.predict(x)).max())
    np.testing.assert_array_equal(back.network.y_min.numpy(), data[0].tangent_min.values)
    assert back.initial_state == model.initial_state and len(back.initial_state["features"]) == 6
    np.testing.assert_allclose(back.initial_state["targets"], data[0].tangent.isel(step=0).mean("gp").values)
    assert back.network.net[0].weight.dtype == torch.float64


def test_ensemble_is_the_mean_of_its_members(data, tmp_path):
    """K networks from K seeds; member 0 is the single network of the same seed; the model predicts
    their mean, whose MAE cannot exceed the members' mean MAE (triangle inequality), and a
    reloaded file predicts the same."""
    single, _, _ = train(*data, "sigma", FAST, seed=3)
    ensemble, losses, mae = train(*data, "sigma", dict(FAST, ensemble_size=3), seed=3)
    assert isinstance(ensemble.network, EnsembleMLP) and ensemble.ensemble_size == 3
    # member 0 was fitted in the members' stacked batch: float32 rounding of the batched products
    # (bit-identical with some BLAS builds, not all), as test_members_fitted_together_... allows
    for (name, pa), pb in zip(single.network.state_dict().items(), ensemble.members[0].state_dict().values()):
        np.testing.assert_allclose(pa.numpy(), pb.numpy(), rtol=1e-5, atol=1e-6, err_msg=name)
    assert not torch.equal(ensemble.members[1].net[0].weight, ensemble.members[2].net[0].weight)
    assert len(set(ensemble.training["member_seeds"])) == 3 and ensemble.training["seed"] == single.training["seed"]
    assert losses.groupby("member").epoch.max().tolist() == [FAST["epochs"]] * 3

    x, y = features(data[1]), targets(data[1], "sigma")
    with torch.no_grad():
        per_member = np.stack([m(torch.as_tensor(x, dtype=torch.float32)).double().numpy() for m in ensemble.members])
    np.testing.assert_allclose(ensemble.predict(x), per_member.mean(axis=0), rtol=1e-5, atol=1e-6 * np.abs(y).max())
    member_mae = np.abs(per_member - y).mean(axis=1)  # [member, target]
    assert np.all(mae.heldout_mae_pa.values <= member_mae.mean(axis=0) * (1 + 1e-5))

    ensemble.save(tmp_path / "ens.pt")
    back = SurrogateModel.load(tmp_path / "ens.pt")
    assert back.ensemble_size == 3 and back.training["member_seeds"] == ensemble.training["member_seeds"]
    np.testing.assert_allclose(back.predict(x), ensemble.predict(x), rtol=1e-4, atol=1e-4 * np.abs(y).max())
    with pytest.raises(ValueError, match="member 1 has another scaling"):
        other = SurrogateModel.create("sigma", True, {"x_min": np.zeros(9), "x_max": np.ones(9),
                                                      "y_min": np.zeros(6), "y_max": np.ones(6)}, FAST)
        EnsembleMLP([ensemble.members[0], other.network])


def test_members_fitted_together_are_the_members_fitted_one_by_one(data, monkeypatch):
    """The members of an ensemble are fitted as one stacked batch; each is the network that fitting
    the members one after the other gives: the same batches and Adam updates, so the same weights
    and loss histories (measured: bit-identical; allowed: float32 rounding of the batched products)."""
    settings = dict(FAST, ensemble_size=3, epochs=20)
    together, losses_together, _ = train(*data, "sigma", settings, seed=3)

    def one_by_one(nets, fit, settings, seeds, labels, logger):
        return [training._fit_network(net, fit, settings, seed, label, logger) for net, seed, label in zip(nets, seeds, labels)]

    monkeypatch.setattr(training, "_fit_together", one_by_one)
    alone, losses_alone, _ = train(*data, "sigma", settings, seed=3)
    for k, (a, b) in enumerate(zip(together.members, alone.members)):
        for name, value in a.state_dict().items():
            np.testing.assert_allclose(value.numpy(), b.state_dict()[name].numpy(), rtol=1e-5, atol=1e-6, err_msg=f"member {k} {name}")
    columns = ["member", "epoch", "train_loss", "heldout_loss"]
    np.testing.assert_allclose(losses_together[columns].to_numpy(), losses_alone[columns].to_numpy(), rtol=1e-5)


def test_format_1_model_files_still_load(data, tmp_path):
    """Files written before ensembles (format 1: one network under "state_dict") load unchanged."""
    model, _, _ = train(*data, "sigma", FAST, seed=2)
    model.save(tmp_path / "new.pt")
    payload = torch.load(tmp_path / "new.pt", weights_only=True)
    payload["format"] = "granular_multiscale.surrogate/1"
    payload["state_dict"] = payload.pop("members")[0]
    torch.save(payload, tmp_path / "old.pt")
    x = features(data[1])
    np.testing.assert_array_equal(SurrogateModel.load(tmp_path / "old.pt").predict(x),
                                  SurrogateModel.load(tmp_path / "new.pt").predict(x))


def test_model_file_errors(tmp_path):
    with pytest.raises(ModelFileError, match="not found"):
        SurrogateModel.load(tmp_path / "none.pt")
    (tmp_path / "junk.pt").write_bytes(b"not a model")
    with pytest.raises(ModelFileError, match="junk.pt"):
        SurrogateModel.load(tmp_path / "junk.pt")
    torch.save({"format": "other"}, tmp_path / "other.pt")
    with pytest.raises(ModelFileError, match="not a surrogate model"):
        SurrogateModel.load(tmp_path / "other.pt")


def test_bad_settings_are_named(data):
    with pytest.raises(TrainingError, match="surrogate.loss"):
        train(*data, "sigma", dict(FAST, loss="huber"), seed=0)
    with pytest.raises(ValueError, match="surrogate.activation"):
        train(*data, "sigma", dict(FAST, activation="swish"), seed=0)
    if not torch.cuda.is_available():
        with pytest.raises(TrainingError, match="surrogate.device"):
            train(*data, "sigma", dict(FAST, device="cuda"), seed=0)
    with pytest.raises(TrainingError, match="loss is not finite at epoch"):
        train(*data, "sigma", dict(FAST, learning_rate=1e30, loss="mse", epochs=3), seed=0)
    with pytest.raises(TrainingError, match="surrogate.ensemble_size"):
        train(*data, "sigma", dict(FAST, ensemble_size=0), seed=0)


def test_loss_figure(data, tmp_path):
    """The figure's two curves are the training and held-out loss per logged epoch that train returned."""
    _, losses, _ = train(*data, "sigma", FAST, seed=0)
    drawn = plot_losses({"NNσ": losses}, tmp_path / "loss.png")
    assert list(drawn) == ["NNσ"] and list(drawn["NNσ"]) == ["training", "held out"]
    for line, column in (("training", "train_loss"), ("held out", "heldout_loss")):
        epochs, loss = drawn["NNσ"][line]
        np.testing.assert_array_equal(epochs, losses["epoch"])
        np.testing.assert_array_equal(loss, losses[column])
    assert not np.array_equal(losses["train_loss"], losses["heldout_loss"])  # the two curves differ
    with Image.open(tmp_path / "loss.png") as image:
        assert image.size == (720, 480)  # one 6 x 4 inch panel at 120 dpi


def test_roundoff_columns_are_constant_in_the_scaling():
    """A shear strain that is zero up to roundoff at every training point must not be blown up to O(1)."""
    from granular_multiscale.surrogate.models import column_groups, scale_of

    x_min = np.array([-0.02, -0.02, -0.05, -1e-3, -1e-3, -3e-21, 0.0, 0.0, 0.0])
    x_max = np.array([0.01, 0.01, 0.0, 1e-3, 1e-3, 2e-21, 0.06, 0.09, 4e-17])
    scale = scale_of(x_min, x_max, column_groups(9, 6))
    np.testing.assert_array_equal(scale, [0.03, 0.03, 0.05, 2e-3, 2e-3, 1.0, 0.06, 0.09, 4e-17])
    # φ3 is legitimately tiny (a product of six strains): its own group keeps its span
    assert scale_of([0.0, 0.0], [0.0, 0.0], [0, 0]).tolist() == [1.0, 1.0]
    model = SurrogateModel.create("sigma", True, {"x_min": x_min, "x_max": x_max, "y_min": np.zeros(6),
                                                  "y_max": np.array([1e6, 1e6, 1e6, 1e4, 1e4, 1e-10])}, FAST)
    x = torch.tensor([[0.0, 0.0, -0.01, 0.0, 0.0, 1e-12, 0.01, 0.01, 0.0]])
    assert float(model.network.scale_x(x)[0, 5].abs()) < 1e-9
    np.testing.assert_allclose(model.network.y_scale.numpy(), [1e6, 1e6, 1e6, 1e4, 1e4, 1.0], rtol=1e-6)


def test_bootstrap_rows_are_whole_trajectories_drawn_with_replacement():
    trajectories = np.repeat([0, 1, 2, 3, 4], [3, 1, 2, 2, 1])  # samples of five trajectories of unequal length
    from granular_multiscale.surrogate.training import bootstrap_rows

    rows = bootstrap_rows(trajectories, seed=7)
    np.testing.assert_array_equal(rows, bootstrap_rows(trajectories, seed=7))  # seeded
    drawn = np.random.default_rng(7).choice(5, size=5, replace=True)
    expected = np.concatenate([np.flatnonzero(trajectories == t) for t in np.sort(drawn)])
    np.testing.assert_array_equal(np.sort(rows), np.sort(expected))  # every sample of each drawn trajectory, once per draw
    assert any(not np.array_equal(rows, bootstrap_rows(trajectories, seed=s)) for s in range(8, 12))


def test_ensemble_members_on_bootstrap_samples_of_trajectories(data):
    """ensemble_resampling: trajectories: member k is fitted to its own bootstrap sample of the
    training Gauss points, so even member 0 differs from the single network of its seed; the
    choice is recorded in the model; an unknown choice is refused naming the key."""
    from granular_multiscale.surrogate.dataset import sample_trajectories

    settings = dict(FAST, ensemble_size=2)
    seeds_only, _, _ = train(*data, "sigma", settings, seed=3)
    bagged, _, _ = train(*data, "sigma", dict(settings, ensemble_resampling="trajectories"), seed=3)
    again, _, _ = train(*data, "sigma", dict(settings, ensemble_resampling="trajectories"), seed=3)
    assert not torch.equal(seeds_only.members[0].net[0].weight, bagged.members[0].net[0].weight)
    for (name, pa), pb in zip(bagged.network.state_dict().items(), again.network.state_dict().values()):
        assert torch.equal(pa, pb), name  # deterministic
    assert bagged.training["ensemble_resampling"] == "trajectories"
    assert seeds_only.training["ensemble_resampling"] == "none"
    trajectories = sample_trajectories(data[0])
    assert trajectories.size == features(data[0]).shape[0] and set(trajectories) == set(range(data[0].sizes["gp"]))
    with pytest.raises(TrainingError, match="surrogate.ensemble_resampling"):
        train(*data, "sigma", dict(settings, ensemble_resampling="points"), seed=0)
