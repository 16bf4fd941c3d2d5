"""RVE preparation with YADE: a periodic cell of spheres (paper Table 1), isotropically
consolidated to the confining pressure without friction, then friction restored.

Run in its own process (YADE rebinds globals on import)::

    python -m granular_multiscale.dem.rve spec.json packing.yade.gz summary.json

or from Python through :func:`prepare_packing`, which does exactly that.

Steps
-----
1. ``SpherePack.makeCloud`` in a periodic cube sized for ``initial_porosity``; radii uniform
   in [d_min/2, d_max/2] (Table 1: 2–8 mm, mean 5 mm), seeded.
2. Hertz–Mindlin contacts (``Ip2_FrictMat_FrictMat_MindlinPhys`` +
   ``Law2_ScGeom_MindlinPhys_Mindlin``), E = 0.3 GPa, ν = 0.3, ρ = 2650 kg/m³, μ = 0 while
   consolidating (a dense, isotropic packing, as in the paper).
3. ``PeriTriaxController`` compacts the cloud to a jammed packing at a mean stress near −p.
   It controls the normal stresses only (and, jammed, may keep a deviator of 1–3 %), while
   a frictionless packing of a few hundred spheres jams with shear stresses of a few % of p
   (random fabric), so a second stage servo-controls the full
   symmetric stress tensor through the cell's velocity gradient, using YADE's contact
   stiffness tangent as the gain, until every component is within ``stress_tolerance`` · p
   of −p δij and the unbalanced force is below ``unbalanced_tolerance``.
4. μ restored to 0.5 in the material and in every existing contact, particle velocities
   and the cell's velocity gradient zeroed, the controller removed, local damping set for
   the FEM–DEM stage. The scene is saved in YADE's own format (``O.save``).
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from .. import integrity


@dataclass
class RVESpec:
    """Everything that defines one packing (all SI units)."""

    n_spheres: int = 400
    seed: int = 0
    diameter_min: float = 0.002
    diameter_max: float = 0.008
    density: float = 2650.0
    youngs_modulus: float = 3.0e8
    poisson_ratio: float = 0.3
    friction: float = 0.5
    pressure: float = 1.0e5
    initial_porosity: float = 0.7
    timestep_safety: float = 0.8
    consolidation_damping: float = 0.4
    max_strain_rate: float = 5.0
    stress_tolerance: float = 2.0e-3
    unbalanced_tolerance: float = 5.0e-3
    max_steps: int = 3_000_000
    damping: float = 0.2  # local damping left in the saved scene for the FEM–DEM stage
    extra: dict = field(default_factory=dict)

    @classmethod
    def from_config(cls, config: dict, seed: int) -> "RVESpec":
        dem = config["dem"]
        cons = dem["consolidation"]
        return cls(
            n_spheres=int(dem["n_spheres"]),
            seed=int(seed),
            diameter_min=float(dem["diameter_min"]),
            diameter_max=float(dem["diameter_max"]),
            density=float(dem["density"]),
            youngs_modulus=float(dem["youngs_modulus"]),
            poisson_ratio=float(dem["poisson_ratio"]),
            friction=float(dem["friction"]),
            pressure=float(config["specimen"]["confining_pressure"]),
            initial_porosity=float(cons["initial_porosity"]),
            timestep_safety=float(dem["timestep_safety"]),
            consolidation_damping=float(cons["damping"]),
            max_strain_rate=float(cons["max_strain_rate"]),
            stress_tolerance=float(cons["stress_tolerance"]),
            unbalanced_tolerance=float(cons["unbalanced_tolerance"]),
            max_steps=int(cons["max_steps"]),
            damping=float(dem["damping"]),
        )

    def check(self) -> None:
        if not 0 < self.diameter_min <= self.diameter_max:
            raise ValueError(f"dem.diameter_min/diameter_max: need 0 < min <= max, got {self.diameter_min}, {self.diameter_max}")
        if self.n_spheres < 10:
            raise ValueError(f"dem.n_spheres: a periodic RVE needs at least 10 spheres, got {self.n_spheres}")
        if not 0.4 <= self.initial_porosity < 0.95:
            raise ValueError(f"dem.consolidation.initial_porosity must be in [0.4, 0.95), got {self.initial_porosity}")

    def mean_sphere_volume(self) -> float:
        """E[4/3 π r³] for r uniform in [r_min, r_max]."""
        a, b = self.diameter_min / 2, self.diameter_max / 2
        mean_r3 = a**3 if b == a else (b**4 - a**4) / (4 * (b - a))
        return 4.0 / 3.0 * math.pi * mean_r3

    def cell_size(self) -> float:
        return (self.n_spheres * self.mean_sphere_volume() / (1 - self.initial_porosity)) ** (1 / 3)


# --------------------------------------------------------------------------- YADE side
# Everything below runs only in a process that imported YADE (see yade_env.import_yade).


def _matrix3_to_numpy(m) -> np.ndarray:
    return np.array([[m[i, j] for j in range(3)] for i in range(3)])


def _matrix6_to_numpy(m) -> np.ndarray:
    return np.array([[m[i, j] for j in range(6)] for i in range(6)])


def stress_voigt(stress33: np.ndarray) -> np.ndarray:
    """Symmetrised 3×3 -> Voigt 11,22,33,23,13,12."""
    s = 0.5 * (stress33 + stress33.T)
    return np.array([s[0, 0], s[1, 1], s[2, 2], s[1, 2], s[0, 2], s[0, 1]])


def stress_and_tangent(utils) -> tuple[np.ndarray, np.ndarray]:
    """The cell's Love–Weber stress (Voigt) and contact-stiffness tangent (6×6, symmetric), from
    ``utils.getStressAndTangent``; YADE fills only the upper triangle (j >= i) of the tangent."""
    s, D = utils.getStressAndTangent(symmetry=True)
    upper = np.triu(_matrix6_to_numpy(D))
    return stress_voigt(_matrix3_to_numpy(s)), upper + np.triu(upper, 1).T


def voigt_to_matrix3(v, Matrix3):
    """Voigt 11,22,33,23,13,12 (tensorial shear) -> symmetric YADE Matrix3."""
    v = [float(x) for x in v]
    return Matrix3(v[0], v[5], v[4], v[5], v[1], v[3], v[4], v[3], v[2])


def build_engines(damping: float, with_controller: bool = False, controller_kwargs: dict | None = None):
    from yade.wrapper import (
        Bo1_Sphere_Aabb,
        ForceResetter,
        Ig2_Sphere_Sphere_ScGeom,
        InsertionSortCollider,
        InteractionLoop,
        Ip2_FrictMat_FrictMat_MindlinPhys,
        Law2_ScGeom_MindlinPhys_Mindlin,
        NewtonIntegrator,
        PeriTriaxController,
    )

    engines = [
        ForceResetter(),
        InsertionSortCollider([Bo1_Sphere_Aabb()]),
        InteractionLoop(
            [Ig2_Sphere_Sphere_ScGeom()],
            [Ip2_FrictMat_FrictMat_MindlinPhys()],
            [Law2_ScGeom_MindlinPhys_Mindlin()],
        ),
    ]
    if with_controller:
        engines.append(PeriTriaxController(label="consolidation", **(controller_kwargs or {})))
    engines.append(NewtonIntegrator(damping=damping, label="newton"))
    return engines


def measure(O) -> dict:
    """State of the current scene: stress, porosity, coordination number, ..."""
    from yade import utils

    stress33 = _matrix3_to_numpy(utils.getStress())
    porosity = float(utils.porosity())
    n = len(O.bodies)
    return {
        "stress_tensor": stress33.tolist(),
        "stress_voigt": stress_voigt(stress33).tolist(),
        "mean_stress": float(np.trace(stress33) / 3),
        "porosity": porosity,
        "void_ratio": porosity / (1 - porosity),
        "coordination_number": float(utils.avgNumInteractions()),
        "mechanical_coordination_number": float(utils.avgNumInteractions(skipFree=True)),
        "n_contacts": int(O.interactions.countReal()),
        "n_spheres": n,
        "unbalanced_force": float(utils.unbalancedForce()),
        "cell_size": [float(O.cell.hSize[i, i]) for i in range(3)],
        "timestep": float(O.dt),
    }


def _stress_error(O, pressure: float) -> float:
    from yade import utils

    s = _matrix3_to_numpy(utils.getStress())
    return float(np.abs(0.5 * (s + s.T) + pressure * np.eye(3)).max() / pressure)


def consolidate(spec: RVESpec, log=print) -> dict:
    """Build and consolidate one packing in the current (YADE) process; returns the summary."""
    from yade import pack, utils
    from yade.minieigenHP import Matrix3, Vector3
    from yade.wrapper import FrictMat, Omega

    spec.check()
    O = Omega()
    O.reset()
    t0 = time.perf_counter()
    size = spec.cell_size()
    O.periodic = True
    O.cell.setBox(size, size, size)
    mat = O.materials.append(
        FrictMat(young=spec.youngs_modulus, poisson=spec.poisson_ratio, density=spec.density, frictionAngle=0.0, label="grains")
    )
    sp = pack.SpherePack()
    r_mean = 0.25 * (spec.diameter_min + spec.diameter_max)
    fuzz = (spec.diameter_max - spec.diameter_min) / (spec.diameter_max + spec.diameter_min)
    placed = sp.makeCloud(
        minCorner=(0, 0, 0), maxCorner=(size, size, size), rMean=r_mean, rRelFuzz=fuzz,
        num=spec.n_spheres, periodic=True, seed=spec.seed,
    )
    if placed != spec.n_spheres:
        raise RuntimeError(
            f"makeCloud placed {placed} of {spec.n_spheres} spheres; raise dem.consolidation.initial_porosity "
            f"(now {spec.initial_porosity})"
        )
    sp.toSimulation(material=mat)
    p = spec.pressure
    O.engines = build_engines(
        spec.consolidation_damping,
        with_controller=True,
        controller_kwargs=dict(
            goal=(-p, -p, -p), stressMask=7, maxUnbalanced=spec.unbalanced_tolerance,
            relStressTol=spec.stress_tolerance, absStressTol=0.0,
            maxStrainRate=(spec.max_strain_rate,) * 3, dynCell=False,
        ),
    )
    O.dt = spec.timestep_safety * utils.PWaveTimeStep()

    chunk = 500
    # Stage 1: PeriTriaxController compacts the cloud until it jams at about the target mean
    # stress. (Once jammed, its per-axis control can hang on to a deviator of 1–3 % for good;
    # stage 2 removes that.)
    while O.iter < spec.max_steps // 2:
        for _ in range(chunk):
            O.step()
        mean_err = abs(np.trace(_matrix3_to_numpy(utils.getStress())) / 3 + p) / p
        if mean_err < 0.02 and utils.unbalancedForce() < 5 * spec.unbalanced_tolerance:
            break
    stage1_steps = O.iter
    log(f"rve seed {spec.seed}: stage 1 (PeriTriaxController) done after {O.iter} steps, "
        f"porosity {utils.porosity():.4f}, {time.perf_counter() - t0:.1f} s")

    # Stage 2: servo on the full symmetric stress tensor (normal and shear components).
    O.engines = build_engines(spec.consolidation_damping)
    gain, servo_steps = 0.5, 200
    while O.iter < spec.max_steps:
        s, D = stress_and_tangent(utils)
        err = np.abs(s + p * np.array([1, 1, 1, 0, 0, 0])).max() / p
        if err < spec.stress_tolerance and utils.unbalancedForce() < spec.unbalanced_tolerance:
            break
        target = -p * np.array([1, 1, 1, 0, 0, 0])
        d_eng = gain * np.linalg.solve(D, target - s)  # engineering strain increment
        d_eps = d_eng * np.array([1, 1, 1, 0.5, 0.5, 0.5])
        rate = d_eps / (servo_steps * O.dt)
        cap = spec.max_strain_rate
        if np.abs(rate).max() > cap:
            rate *= cap / np.abs(rate).max()
        O.cell.velGrad = voigt_to_matrix3(rate, Matrix3)
        for _ in range(servo_steps):
            O.step()
    O.cell.velGrad = Matrix3.Zero
    if O.iter >= spec.max_steps:
        raise RuntimeError(
            f"consolidation of packing seed {spec.seed} did not reach {spec.stress_tolerance} relative stress "
            f"error and unbalanced force {spec.unbalanced_tolerance} within dem.consolidation.max_steps={spec.max_steps}"
        )
    state_consolidated = measure(O)
    log(f"rve seed {spec.seed}: consolidated after {O.iter} steps, stress error "
        f"{_stress_error(O, p):.2e}, unbalanced {state_consolidated['unbalanced_force']:.2e}")

    # Friction back to μ, in the material and in every existing contact; particles at rest.
    friction_angle = math.atan(spec.friction)
    utils.setContactFriction(friction_angle)
    for m in O.materials:
        m.frictionAngle = friction_angle
    O.engines = build_engines(spec.damping)
    # velGrad assignments are deferred to the next step (Cell.nextVelGrad): two steps make the
    # cell's current and previous velocity gradients zero, then the particles are stopped.
    O.cell.velGrad = Matrix3.Zero
    for _ in range(2):
        O.step()
    for b in O.bodies:
        b.state.vel = Vector3.Zero
        b.state.angVel = Vector3.Zero
    check = [i.phys.tangensOfFrictionAngle for i in O.interactions if i.isReal]
    if check and not np.allclose(check, spec.friction):
        raise RuntimeError("friction was not restored in every contact")

    summary = measure(O)
    summary.update(
        steps=int(O.iter),
        stage1_steps=int(stage1_steps),
        wall_time=time.perf_counter() - t0,
        particle_step_time=(time.perf_counter() - t0) / max(O.iter, 1) / len(O.bodies),
        friction=spec.friction,
        spec={k: v for k, v in asdict(spec).items() if k != "extra"},
        stress_error=_stress_error(O, p),
    )
    return summary


def main(argv: list[str]) -> int:
    spec_path, packing_path, summary_path = argv
    from .yade_env import import_yade

    O = import_yade()
    spec = RVESpec(**json.loads(Path(spec_path).read_text()))
    summary = consolidate(spec, log=lambda m: print(m, file=sys.stderr, flush=True))
    packing_path = Path(packing_path)
    tmp = packing_path.with_name(packing_path.name + ".tmp" + "".join(packing_path.suffixes))
    O.save(str(tmp))
    integrity.record(packing_path, content=tmp)
    os.replace(tmp, packing_path)
    summary["packing"] = str(packing_path)
    Path(summary_path).write_text(json.dumps(summary, indent=1))
    return 0


# --------------------------------------------------------------------------- caller side


def prepare_packing(spec: RVESpec, packing_path: str | Path, timeout: float | None = None) -> dict:
    """Consolidate one packing in a fresh YADE process; returns its summary dict."""
    from tempfile import TemporaryDirectory

    from .yade_env import child_env

    packing_path = Path(packing_path)
    packing_path.parent.mkdir(parents=True, exist_ok=True)
    with TemporaryDirectory() as tmp:
        spec_file = Path(tmp) / "spec.json"
        summary_file = Path(tmp) / "summary.json"
        spec_file.write_text(json.dumps(asdict(spec)))
        cmd = [sys.executable, "-m", "granular_multiscale.dem.rve", str(spec_file), str(packing_path), str(summary_file)]
        proc = subprocess.run(cmd, env=child_env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, timeout=timeout)
        if proc.returncode != 0:
            raise RuntimeError(f"RVE preparation (seed {spec.seed}) failed:\n{proc.stderr[-4000:]}")
        summary = json.loads(summary_file.read_text())
    summary["log"] = proc.stderr.strip().splitlines()[-5:]
    return summary


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
