"""The reference rule end to end: the exact snakemake command of the README at the tiny scale."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from granular_multiscale.data import read_run
from granular_multiscale.plan import Layout

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_fem_elastoplastic_rule_writes_both_paths(tmp_path):
    out = tmp_path / "x"
    L = Layout(out)
    targets = [L.run("fem_elastoplastic", "path1"), L.run("fem_elastoplastic", "path2")]
    snakemake = Path(sys.executable).with_name("snakemake")
    command = [str(snakemake), "-j2", "--configfile", "config/tiny.yaml",
               "--config", "reference_material=elastoplastic", f"output_dir={out}", "--", *targets]
    result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    steps = {"path1": 62, "path2": 58}
    for target in targets:
        ds = read_run(target)
        name = Path(target).stem
        assert ds.attrs["method"] == "elastoplastic"
        assert ds.sizes["step"] == steps[name] and ds.sizes["gp"] == 16
        assert ds.axial_strain.values[-1] == pytest.approx(0.045)
        q = -ds.top_force.values / 0.25 - 1e5  # deviator from the platen force, Pa
        unloading = ds.phase.values == "unloading"
        # rough platens on a 1×1×2 mesh restrain the dilatant specimen: stiffer than the
        # homogeneous ~305 kPa at 4.5 %, but bounded
        assert 3.0e5 < q[-1] < 1.0e6
        # the unloading is elastic (equal decrements); Path2's stays in compression, as in the
        # FEM–DEM runs, while Path1's reaches the isotropic state (q ~ 0)
        decrements = np.diff(q[unloading])
        np.testing.assert_allclose(decrements, decrements[0], rtol=1e-6)
        assert decrements[0] < 0
        assert q[unloading].min() > (0.1 * q[np.flatnonzero(unloading)[0] - 1] if name == "path2" else -0.05 * q[-1])
        assert np.all(ds.cutbacks.values == 0)
        assert Path(L.log(f"fem_elastoplastic/{name}")).read_text().count("axial strain") == steps[name]
        assert Path(L.benchmark(f"fem_elastoplastic/{name}")).exists()
