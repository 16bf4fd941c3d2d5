"""What every bench shares (bench/common.py): the top-force error, the command line whose record
goes where the plan's layout says, the config merged as Snakemake merges --configfile files, the
pipeline's networks; and that every bench uses them, imports no other bench and leaves sys.path
alone."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import numpy as np
import pytest

from analysis_fixtures import PATH2, make_run
from granular_multiscale.config import CONFIG_DIR, load_config
from granular_multiscale.plan import Layout

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "bench"
sys.path.insert(0, str(BENCH))  # the benches are scripts; their shared module sits beside them

import common  # noqa: E402

TINY = str(CONFIG_DIR / "tiny.yaml")
#: the bench scripts: every file of bench/ but the shared module and the docs renderer
BENCHES = sorted(f for f in BENCH.glob("*.py") if f.name not in ("common.py", "update_docs.py"))


def test_top_force_error_is_the_largest_difference_in_percent_of_the_reference_peak():
    reference = make_run("reference")
    force = reference["top_force"].values
    peak = np.abs(force).max()
    phases = reference["phase"].values.astype(str)
    unloading = int(np.flatnonzero(phases == "unloading")[2])
    reloading = int(np.flatnonzero(phases == "reloading")[-1])
    run = reference.copy(deep=True)
    run["top_force"].values[unloading] += 0.05 * peak  # 5 % of the peak, during the unloading
    run["top_force"].values[reloading] -= 0.02 * peak  # 2 %, at the end of the reloading
    assert common.top_force_error_pct(reference, run) == pytest.approx(5.0)
    assert common.top_force_error_pct(reference, run, "unloading") == pytest.approx(5.0)
    assert common.top_force_error_pct(reference, run, "reloading") == pytest.approx(2.0)
    assert common.top_force_error_pct(reference, run, "loading") == 0.0
    assert common.curve_error_pct(reference, run, "volumetric_strain") == {
        "all": 0.0, "loading": 0.0, "unloading": 0.0, "reloading": 0.0}


def test_top_force_error_compares_runs_of_other_meshes_and_runs_that_stopped_early():
    reference = make_run("reference")
    quarter = reference.isel(gp=slice(0, 4))  # a quarter model: fewer Gauss points, the same load curves
    assert common.top_force_error_pct(reference, quarter) == 0.0
    # a run that stopped early (attribute completed = 0) is compared on the steps it reached, in % of
    # the reference's peak over those steps
    reached = PATH2.n_steps // 2
    stopped = reference.isel(step=slice(0, reached)).copy(deep=True)
    stopped.attrs["completed"] = 0
    stopped["top_force"].values[3] *= 1.1
    force = reference["top_force"].values[:reached]
    assert common.top_force_error_pct(reference, stopped) == pytest.approx(10 * abs(force[3]) / abs(force).max())


def test_the_record_goes_where_the_layout_puts_it_unless_out_is_given(tmp_path):
    args = common.bench_parser("unit", "what it measures").parse_args([])
    assert args.config == load_config()
    assert args.out == Path(Layout(load_config()["output_dir"]).bench("unit")) == Path("results/bench/unit.json")
    tiny = common.bench_parser("unit", "doc").parse_args(["--configfile", TINY])
    assert tiny.config == load_config(TINY)
    assert tiny.out == Path(Layout("results/tiny").bench("unit"))
    assert common.bench_parser("unit", "doc", configfile=[TINY]).parse_args([]).out == tiny.out
    given = common.bench_parser("unit", "doc").parse_args(["--out", str(tmp_path / "r.json")])
    assert given.out == tmp_path / "r.json"
    assert common.run_folder(tiny) == Path("results/tiny/bench/unit_runs")


def test_the_record_holds_the_options_and_the_config_that_differ_from_the_defaults(tmp_path):
    parser = common.bench_parser("unit", "doc")
    parser.add_argument("--steps", type=int, default=12)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args(["--configfile", TINY, "--steps", "3", "--out", str(tmp_path / "unit.json")])
    record = parser.measurement(args, path="path2").finish({"seconds": np.float64(1.5), "done": np.bool_(True)},
                                                            args.out)
    settings = record["settings"]
    assert settings["configfile"] == [TINY] and settings["steps"] == 3 and "workers" not in settings
    assert settings["config_difference"]["output_dir"] == "results/tiny" and settings["path"] == "path2"
    assert (tmp_path / "unit.json").read_text().count('"seconds": 1.5') == 1
    default = common.bench_parser("unit", "doc").parse_args(["--out", str(tmp_path / "d.json")])
    assert "config_difference" not in common.bench_parser("unit", "doc").measurement(default).settings


def test_config_files_merge_over_the_default_config_as_snakemake_merges_them():
    config = common.bench_config([str(CONFIG_DIR / "new_paths.yaml")])
    assert {"path1", "path2", "path3", "path4"} <= set(config["load_paths"])
    assert config["output_dir"] == load_config()["output_dir"]  # what the overlay leaves out: config.yaml's
    assert common.bench_config([TINY], {"dem.n_spheres": 100})["dem"]["n_spheres"] == 100


def test_the_pipeline_networks_are_named_by_the_layout():
    config = load_config(TINY)
    layout = Layout(config["output_dir"])
    assert common.pipeline_models(config) == (Path(layout.model("sigma")), Path(layout.model("tangent")))
    assert common.pipeline_models(config, "elsewhere/models") == (Path("elsewhere/models/nn_sigma.pt"),
                                                                    Path("elsewhere/models/nn_tangent.pt"))


@pytest.mark.parametrize("bench", BENCHES, ids=lambda f: f.name)
def test_every_bench_uses_the_shared_command_line_and_record(bench):
    tree = ast.parse(bench.read_text())
    from_common = {alias.name for node in ast.walk(tree) if isinstance(node, ast.ImportFrom) and node.module == "common"
                   for alias in node.names}
    assert from_common & {"bench_parser", "Measurement"}, f"{bench.name} does not use common's command line or record"
    called = {node.func.id for node in ast.walk(tree) if isinstance(node, ast.Call) and isinstance(node.func, ast.Name)}
    assert "bench_parser" in called or "Measurement" in called
    assert not any(isinstance(node, ast.Attribute) and node.attr == "path" and isinstance(node.value, ast.Name)
                   and node.value.id == "sys" for node in ast.walk(tree)), f"{bench.name} touches sys.path"
    others = {f.stem for f in BENCH.glob("*.py")} - {"common"}
    imported = {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom) and node.module}
    imported |= {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import) for alias in node.names}
    assert not imported & others, f"{bench.name} imports another bench: {sorted(imported & others)}"
    assert "argparse" not in imported, f"{bench.name} builds its own command line"
