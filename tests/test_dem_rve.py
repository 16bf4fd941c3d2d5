"""YADE in the venv and the consolidated RVE packing (rule rve)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from dem_fixtures import TEST_SPHERES, packing

from granular_multiscale.dem.rve import RVESpec
from granular_multiscale.dem.yade_env import child_env

P0 = 1.0e5


def _yade(code: str, timeout: float = 300) -> dict:
    """Run code in a fresh YADE process; it prints one JSON line last."""
    out = subprocess.run([sys.executable, "-c", code], env=child_env(), capture_output=True, text=True, timeout=timeout)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.needs_yade
def test_yade_steps_a_periodic_packing_in_the_venv():
    """YADE imports in this venv, steps a small periodic packing, and reads its stress."""
    result = _yade("""
import json
import os
from granular_multiscale.dem.yade_env import import_yade
O = import_yade()
from yade import pack, utils
from yade.minieigenHP import Matrix3
from granular_multiscale.dem.rve import build_engines
O.periodic = True
O.cell.setBox(0.03, 0.03, 0.03)
mat = O.materials.append(__import__('yade.wrapper', fromlist=['FrictMat']).FrictMat(young=3e8, poisson=0.3, density=2650, frictionAngle=0.46))
sp = pack.SpherePack()
n = sp.makeCloud((0, 0, 0), (0.03, 0.03, 0.03), rMean=0.0025, rRelFuzz=0.2, num=60, periodic=True, seed=3)
sp.toSimulation(material=mat)
O.engines = build_engines(0.3)
O.dt = 0.5 * utils.PWaveTimeStep()
O.cell.velGrad = Matrix3(-20, 0, 0, 0, -20, 0, 0, 0, -20)   # shrink the cell until contacts form
for _ in range(400):
    O.step()
s = utils.getStress()
temp_dir = os.path.dirname(O.tmpFilename())
print(json.dumps({"iter": O.iter, "n": len(O.bodies), "threads": O.numThreads, "contacts": O.interactions.countReal(),
                  "stress": [s[i, i] for i in range(3)], "periodic": O.periodic, "temp_dir": temp_dir,
                  "temp_dir_made": os.path.isdir(temp_dir)}))
""")
    assert result["iter"] == 400 and result["n"] == 60 and result["threads"] == 1 and result["periodic"]
    assert result["contacts"] > 0
    # YADE's /tmp/yade-XXXXXX folder goes with the process that imported it
    assert result["temp_dir_made"] and not Path(result["temp_dir"]).exists(), result["temp_dir"]
    assert np.all(np.isfinite(result["stress"])) and np.all(np.array(result["stress"]) < 0)  # compressed: tension-positive stress < 0


def test_spec_from_config_and_geometry():
    spec = RVESpec(n_spheres=1000)
    # radii uniform in [1, 4] mm: mean sphere volume (4/3)π (4⁴ − 1⁴)/(4·3) mm³
    assert spec.mean_sphere_volume() == pytest.approx(4 / 3 * np.pi * 255 / 12 * 1e-9)
    assert spec.cell_size() ** 3 * (1 - spec.initial_porosity) == pytest.approx(1000 * spec.mean_sphere_volume())
    with pytest.raises(ValueError, match="diameter"):
        RVESpec(diameter_min=0.01, diameter_max=0.002).check()


@pytest.mark.needs_yade
@pytest.mark.slow
def test_consolidated_packing_is_isotropic_dense_and_frictional_again(tmp_path_factory):
    path, summary = packing(tmp_path_factory)
    stress = np.asarray(summary["stress_voigt"])
    # isotropic within 1 % of −100 kPa, shear components included
    assert np.abs(stress - (-P0) * np.array([1, 1, 1, 0, 0, 0])).max() <= 0.01 * P0
    assert summary["n_spheres"] == TEST_SPHERES
    # A frictionless, polydisperse (d 2–8 mm) random packing jams dense: porosity 0.29–0.37
    # (monodisperse random close packing is 0.36; a wide size range packs denser).
    assert 0.29 <= summary["porosity"] <= 0.37
    assert summary["void_ratio"] == pytest.approx(summary["porosity"] / (1 - summary["porosity"]))
    # Frictionless packings are isostatic at jamming: mechanical coordination (rattlers
    # excluded) ≈ 6, a little more at 100 kPa where overlaps add contacts; overall Z lower.
    assert 5.9 <= summary["mechanical_coordination_number"] <= 7.5
    assert 4.0 <= summary["coordination_number"] <= summary["mechanical_coordination_number"]
    assert summary["unbalanced_force"] < 5e-3 and summary["steps"] > 0 and summary["wall_time"] > 0

    # the saved scene: μ = 0.5 in the material and in every contact, particles and cell at rest
    state = _yade(f"""
import json, math
from granular_multiscale.dem.yade_env import import_yade
O = import_yade()
O.load({str(path)!r})
from yade import utils
ts = [i.phys.tangensOfFrictionAngle for i in O.interactions if i.isReal]
print(json.dumps({{"mat": [math.tan(m.frictionAngle) for m in O.materials], "contacts": [min(ts), max(ts), len(ts)],
    "vmax": max(b.state.vel.norm() for b in O.bodies), "wmax": max(b.state.angVel.norm() for b in O.bodies),
    "velgrad": max(abs(O.cell.velGrad[i, j]) for i in range(3) for j in range(3)),
    "engines": [type(e).__name__ for e in O.engines], "law": type(O.engines[2].lawDispatcher.functors[0]).__name__,
    "phys": type(O.engines[2].physDispatcher.functors[0]).__name__}}))
""")
    assert state["mat"] == pytest.approx([0.5])
    assert state["contacts"][0] == pytest.approx(0.5) and state["contacts"][1] == pytest.approx(0.5)
    assert state["contacts"][2] == summary["n_contacts"]
    assert state["vmax"] == 0 and state["wmax"] == 0 and state["velgrad"] == 0
    assert "PeriTriaxController" not in state["engines"]
    assert state["law"] == "Law2_ScGeom_MindlinPhys_Mindlin" and state["phys"] == "Ip2_FrictMat_FrictMat_MindlinPhys"


@pytest.mark.needs_yade
@pytest.mark.slow
def test_preparation_is_seeded(tmp_path_factory):
    """Same seed, same packing bits; another seed, another packing."""
    a, sa = packing(tmp_path_factory)
    from granular_multiscale.dem.rve import prepare_packing

    again = prepare_packing(RVESpec(n_spheres=TEST_SPHERES, seed=0), tmp_path_factory.mktemp("again") / "p.yade.gz")
    assert again["stress_voigt"] == sa["stress_voigt"] and again["steps"] == sa["steps"]
    other, so = packing(tmp_path_factory, seed=1)
    assert so["stress_voigt"] != sa["stress_voigt"]
