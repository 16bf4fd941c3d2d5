"""Bad inputs: each gives ONE clear error naming the file or the config key, never a traceback
from deep inside a library or a silent NaN. Pass criterion of every test: the exception type
(or the command's exit status) and the named file/key in its message."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from granular_multiscale.config import ConfigError, load_config, validate_config
from granular_multiscale.data import DataFileError, read_run, write_run
from granular_multiscale.fem.triaxial import TriaxialProblem
from granular_multiscale.materials import Elastoplastic
from granular_multiscale.paths import LoadPath

ROOT = Path(__file__).resolve().parents[1]
SNAKEMAKE = str(Path(sys.executable).with_name("snakemake"))


@pytest.fixture(scope="module")
def run_file(tmp_path_factory):
    problem = TriaxialProblem(elements=(1, 1, 2))
    ds = problem.run(Elastoplastic(16, initial_stress=problem.initial_stress), LoadPath("p", ((3, 0.003),)),
                     progress=False)
    return write_run(ds, tmp_path_factory.mktemp("runs") / "path2.h5", validate_config({}))


# -- damaged files ------------------------------------------------------------------------
@pytest.mark.parametrize("cut", [0.9, 0.5, 0.1])
def test_truncated_run_file_names_the_file(run_file, tmp_path, cut):
    data = run_file.read_bytes()
    damaged = tmp_path / "truncated_run.h5"
    damaged.write_bytes(data[: int(cut * len(data))])
    with pytest.raises(DataFileError, match=r"truncated_run\.h5"):
        read_run(damaged)


def test_run_file_with_a_flipped_block_names_the_file(run_file, tmp_path):
    data = bytearray(run_file.read_bytes())
    data[: 512] = bytes(512)  # the superblock and the root group's header gone
    damaged = tmp_path / "zeroed_run.h5"
    damaged.write_bytes(bytes(data))
    with pytest.raises(DataFileError, match=r"zeroed_run\.h5"):
        read_run(damaged)


def test_corrupt_dataset_file_names_the_file(tmp_path):
    from granular_multiscale.surrogate.dataset import DatasetError, read_dataset

    damaged = tmp_path / "train.h5"
    damaged.write_bytes(np.random.default_rng(0).bytes(4096))
    with pytest.raises(DatasetError, match=r"train\.h5: not a readable dataset file"):
        read_dataset(damaged)


def test_model_file_from_another_feature_set_names_the_file(tmp_path):
    """A model file whose inputs are not the project's features (here two fabric invariants in
    place of φ1, φ2): refused on loading, naming the file and the features."""
    import torch

    from granular_multiscale.surrogate.dataset import feature_names
    from granular_multiscale.surrogate.models import ModelFileError, SurrogateModel

    scaling = {"x_min": np.zeros(8), "x_max": np.ones(8), "y_min": np.zeros(6), "y_max": np.ones(6)}
    settings = validate_config({})["surrogate"]
    SurrogateModel.create("sigma", ("phi1", "phi2"), scaling, settings).save(tmp_path / "ours.pt")
    payload = torch.load(tmp_path / "ours.pt", weights_only=True)
    assert payload["feature_names"] == list(feature_names(("phi1", "phi2")))
    payload["feature_names"] = payload["feature_names"][:6] + ["fabric_a11", "fabric_a22"]
    torch.save(payload, tmp_path / "nn_sigma_fabric.pt")
    with pytest.raises(ModelFileError, match=r"nn_sigma_fabric\.pt.*fabric_a11"):
        SurrogateModel.load(tmp_path / "nn_sigma_fabric.pt")


def test_corrupt_model_file_names_the_file(tmp_path):
    from granular_multiscale.surrogate.models import ModelFileError, SurrogateModel

    damaged = tmp_path / "nn_sigma.pt"
    damaged.write_bytes(np.random.default_rng(1).bytes(4096))
    with pytest.raises(ModelFileError, match=r"nn_sigma\.pt"):
        SurrogateModel.load(damaged)


# -- inconsistent configs -----------------------------------------------------------------
@pytest.mark.parametrize(
    "config, key",
    [
        ({"training_path": "path3"}, "training_path"),
        ({"validation_path": "path9"}, "validation_path"),
        ({"load_paths": {"path1": {"segments": [[10, 0.01]]}}}, "validation_path"),  # path2 no longer defined
        ({"load_paths": {"path2": {"segments": [[9, 0.009], [0, 0.003]]}}}, "load_paths.path2.segments[1][0]"),
        ({"load_paths": {"path2": {"segments": []}}}, "load_paths.path2.segments"),
        ({"load_paths": {"path2": {"segments": [[9, 0.009, 3]]}}}, "load_paths.path2.segments[0]"),
        ({"load_paths": {"path2": {"segments": [[9, float("nan")]]}}}, "load_paths.path2.segments[0]"),
        ({"load_paths": {"path2": {"steps": 9}}}, "load_paths.path2"),
        ({"newton": {"tangent_repair": "cholesky"}}, "newton.tangent_repair"),
        ({"specimen": {"symmetry": "half"}}, "specimen.symmetry"),
    ],
)
def test_inconsistent_config_names_the_key(config, key):
    with pytest.raises(ValueError) as error:  # ConfigError or LoadPathError, both ValueErrors
        validate_config(config)
    assert f"'{key}" in str(error.value)


@pytest.mark.parametrize(
    "content, key",
    [
        ({"training_path": "path3"}, "training_path"),
        ({"load_paths": {"path2": {"segments": [[9, 0.009], [0, 0.003], [42, 0.045]]}}},
         "load_paths.path2.segments[1][0]"),
    ],
)
def test_snakemake_stops_with_one_line_naming_the_key(tmp_path, content, key):
    """Pass criterion: the workflow refuses the config before building the DAG, exit status
    non-zero, the key named, and no Python traceback in the output."""
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({**content, "output_dir": str(tmp_path / "out")}))
    result = subprocess.run([SNAKEMAKE, "-n", "--configfile", str(bad), "--", "all"], cwd=ROOT,
                            capture_output=True, text=True, timeout=300)
    output = result.stdout + result.stderr
    assert result.returncode != 0
    assert f"'{key}'" in output
    assert "Traceback" not in output
    assert not (tmp_path / "out").exists()


def test_config_file_that_is_not_yaml_names_the_file(tmp_path):
    bad = tmp_path / "broken.yaml"
    bad.write_text("specimen: {elements: [1, 1, 2]\n")
    with pytest.raises(ConfigError, match=r"broken\.yaml is not valid YAML"):
        load_config(bad)


# -- missing YADE -------------------------------------------------------------------------
@pytest.fixture(scope="module")
def python_without_yade(tmp_path_factory):
    """A real interpreter with every package of the project's venv except YADE: a fresh venv
    whose .pth lists the project's site-packages and package folder. Python does not process
    .pth files of a directory added that way, so YADE's own .pth (its module path) is absent."""
    import sysconfig

    env = tmp_path_factory.mktemp("venv") / "noyade"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(env)], check=True, timeout=120,
                   capture_output=True)
    purelib = Path(sysconfig.get_paths()["purelib"])
    target = next(env.glob("lib/python3*/site-packages"))
    (target / "project.pth").write_text(f"{purelib}\n{ROOT / 'workflow'}\n")
    python = env / "bin" / "python"
    probe = subprocess.run([str(python), "-c", "import numpy, granular_multiscale; import yade"],
                           capture_output=True, text=True, timeout=120)
    assert "No module named 'yade'" in probe.stderr, probe.stderr[-500:]
    return python


def test_missing_yade_gives_one_clear_error_naming_the_interpreter(python_without_yade):
    """Pass criterion: the set-up check run by a Python without YADE exits 1 with one message
    that names that interpreter and says how to install YADE."""
    result = subprocess.run([str(python_without_yade), "-m", "granular_multiscale.dem.check_yade"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 1
    assert f"YADE is not importable from this Python ({python_without_yade})" in result.stderr
    assert "apt-get install -y yade" in result.stderr
    assert "Traceback" not in result.stderr.split("apt-get install -y yade")[0]
