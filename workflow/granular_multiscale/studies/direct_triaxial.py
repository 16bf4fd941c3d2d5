"""A drained triaxial test driven directly in YADE on one periodic RVE, and the same RVE under
this project's FEM–DEM procedure, to measure the procedure against YADE itself.

Run in its own process (YADE rebinds globals on import)::

    python -m granular_multiscale.studies.direct_triaxial spec.json packing.yade.gz result.json

or from Python through :func:`run_direct`, which does exactly that. ``studies.uniform_fem_dem.run_fem_dem_uniform``
(caller side, no YADE in the calling process) runs the uniform-field FEM–DEM of one RVE
(the reference setting: :func:`fem_dem_config`); :func:`at_strains` and :func:`peak` read q and εv
of either at chosen axial strains, :func:`increments_of` turns either into a replay.
Findings: docs/rve_procedure.md; study: bench/bench_rve_procedure.py.

Modes (``DirectSpec.mode``)
---------------------------
``servo``
    The axial velocity gradient L33 = −strain_rate is held constant from start to end. Every
    ``servo_interval`` DEM steps a servo sets the lateral components of the velocity gradient
    so that σ11 = σ22 = −p (``shear: fixed``: the shear strains stay zero, as in a periodic
    triaxial cell; ``shear: free``: σ23 = σ13 = σ12 = 0 as well, through the shear strain
    rates, the traction-free condition of the FEM specimen with smooth platens). The servo
    predicts the stress change of the next interval with YADE's contact-stiffness tangent
    (``utils.getStressAndTangent``) and learns the part the tangent misses (sliding and
    rearrangement) from the last intervals, so it has integral action: after the first
    0.01 % of axial strain it holds the controlled stresses within 0.25 % of p (measured on
    400-sphere RVEs: at most 0.1–0.2 %; ``servo_error_max`` in the result).
    ``stop_every`` > 0 stops the cell (velGrad = 0 for ``stop_steps`` steps) each time the
    axial strain passes a multiple of it, as the FEM–DEM procedure does at every increment.
``replay``
    Impose a given strain history (``replay_dstrain``: the Voigt strain increments in order,
    tension positive, tensorial shear; :func:`increments_of` makes them from a run) on the
    RVE, each increment as ``worker.Host.impose`` does: velGrad = Δε/(N dt) for N = ``worker.steps_for_increment``
    steps; with ``replay_stops`` then ``stop_steps`` steps at velGrad = 0 (the project's
    procedure: the stresses of a FEM–DEM run with ``dem.snapshot_interval`` 0 to 1e-9 Pa),
    without: the next increment's velGrad follows at once (the same strain path, imposed
    continuously).
``peri_triax``
    YADE's own ``PeriTriaxController`` (stressMask 3: σ11, σ22 at −p; ε33 at −strain_rate),
    quasi-static (``dyn_cell`` False) or with a cell mass (True), for comparison only.

Measures (all modes, every record): the strain is read from the cell itself, the symmetric
part of log(``Cell.trsf``) (= Σ velGrad·dt, the FEM's small strain Σ Δε to 1e-7), at the same
moment as the stress of ``utils.getStress`` (forces of the last step, computed on that cell).
q = (σ11 + σ22)/2 − σ33 (Pa, compression positive), εv = ε11 + ε22 + ε33 (tension positive, so
dilation is positive), axial strain −ε33 (compression positive), as ``volumetric_strain`` and
``axial_strain`` of the run files.
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

REPORT_AT = (0.005, 0.01, 0.02, 0.03, 0.045)
#: the strain rate of the study (1/s): the direct test's, its replays' and its FEM–DEM runs' (the
#: pipeline's default is 5; the study's measurements and the tests' tolerances are at 2.5)
STUDY_STRAIN_RATE = 2.5
MODES = ("servo", "replay", "peri_triax")
SHEAR = ("fixed", "free")
LATERAL = ("independent", "equal")


@dataclass
class DirectSpec:
    """One direct test (all SI units, strains as fractions)."""

    mode: str = "servo"
    pressure: float = 1.0e5
    strain_rate: float = STUDY_STRAIN_RATE  # axial (servo mode), 1/s
    axial_strain: float = 0.045       # end of the test (servo mode), compression positive
    shear: str = "fixed"              # servo: shear strains zero, or shear stresses zero
    lateral: str = "independent"      # servo: σ11 and σ22 each at −p, or one rate for ε11 = ε22 (mean at −p)
    servo_interval: int = 10          # DEM steps between servo updates
    servo_gain: float = 0.5           # fraction of the stress error removed per interval
    servo_memory: float = 0.3         # weight of the newest interval in the learned drift
    tangent_every: int = 10           # servo updates between re-computations of the tangent
    max_lateral_rate: float = 25.0    # cap of each servo-controlled strain rate, 1/s
    stop_every: float = 0.0           # servo: stop the cell each time the axial strain passes a multiple of this
    stop_steps: int = 1               # DEM steps at velGrad = 0 per stop (servo and replay with stops)
    replay_dstrain: list = field(default_factory=list)  # replay: the strain increments, in order
    replay_stops: bool = True
    min_steps: int = 20               # replay: as dem.min_steps
    max_steps: int = 20000            # replay: as dem.max_steps
    replay_rate: float = STUDY_STRAIN_RATE  # replay: as the FEM–DEM run's dem.strain_rate (N per increment)
    damping: float | None = None      # NewtonIntegrator damping; None = the packing's (0.2)
    homo_deform: int | None = None    # Cell.homoDeform; None = the packing's (YADE's default 2)
    dt_factor: float = 1.0            # DEM time step = this × the packing's
    dyn_cell: bool = False            # peri_triax: PeriTriaxController.dynCell (cell mass = the particles')
    record_every: int = 1             # servo: record every this many servo intervals

    def check(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {self.mode!r}")
        if self.shear not in SHEAR:
            raise ValueError(f"shear must be one of {SHEAR}, got {self.shear!r}")
        if self.lateral not in LATERAL:
            raise ValueError(f"lateral must be one of {LATERAL}, got {self.lateral!r}")
        if self.mode == "replay" and not self.replay_dstrain:
            raise ValueError("mode 'replay' needs replay_dstrain (the strain increments)")
        if self.servo_interval < 1 or self.stop_steps < 0:
            raise ValueError("servo_interval must be >= 1 and stop_steps >= 0")


# --------------------------------------------------------------------------- YADE side
# Everything below up to "caller side" runs only in a process that imported YADE.


_TRSF0: list = []


def _cell_strain(O) -> np.ndarray:
    """Voigt (tensorial) strain of the cell since the test started: symmetric part of
    log(trsf · trsf₀⁻¹) (``Cell.trsf`` accumulates from the cell's creation, consolidation
    included; ``_load`` keeps trsf₀)."""
    from scipy.linalg import logm

    from ..dem.rve import _matrix3_to_numpy

    F = _matrix3_to_numpy(O.cell.trsf) @ _TRSF0[0]
    L = np.real(logm(F))
    e = 0.5 * (L + L.T)
    return np.array([e[0, 0], e[1, 1], e[2, 2], e[1, 2], e[0, 2], e[0, 1]])


class _Recorder:
    def __init__(self, O, utils):
        self.O, self.utils = O, utils
        self.rows: list[dict] = []

    def __call__(self, tag: str = "") -> dict:
        from ..dem.rve import _matrix3_to_numpy, stress_voigt

        s = stress_voigt(_matrix3_to_numpy(self.utils.getStress()))
        e = _cell_strain(self.O)
        row = {"iter": int(self.O.iter), "strain": e.tolist(), "stress": s.tolist(),
               "axial_strain": float(-e[2]), "volumetric_strain": float(e[:3].sum()),
               "q": float(0.5 * (s[0] + s[1]) - s[2])}
        if tag:
            row["tag"] = tag
        self.rows.append(row)
        return row


def _load(O, packing: str, damping, homo_deform=None) -> None:
    """The packing as an RVE host holds it: O.load, then a scene-string round trip."""
    from ..dem.rve import _matrix3_to_numpy

    O.load(packing)
    O.stringToScene(O.sceneToString())
    _TRSF0[:] = [np.linalg.inv(_matrix3_to_numpy(O.cell.trsf))]
    if homo_deform is not None:
        O.cell.homoDeform = int(homo_deform)
    if damping is not None:
        for e in O.engines:
            if type(e).__name__ == "NewtonIntegrator":
                e.damping = float(damping)


def _servo_basis(spec: DirectSpec) -> tuple[np.ndarray, np.ndarray]:
    """B (6×m): the Voigt strain-rate directions the servo sets; C (m×6): the stress
    combinations it holds at −p (normal) or 0 (shear). The other components of the strain
    rate are prescribed: L33 = −strain_rate and, with shear fixed, zero shear."""
    I = np.eye(6)
    if spec.lateral == "equal":  # one lateral rate for x and y, holding the mean lateral stress
        B, C = [(I[0] + I[1])], [0.5 * (I[0] + I[1])]
    else:
        B, C = [I[0], I[1]], [I[0], I[1]]
    if spec.shear == "free":
        B += [I[3], I[4], I[5]]
        C += [I[3], I[4], I[5]]
    return np.array(B).T, np.array(C)


def _servo(O, spec: DirectSpec, record: _Recorder) -> dict:
    from yade import utils
    from yade.minieigenHP import Matrix3

    from ..dem.rve import _matrix3_to_numpy, stress_and_tangent, stress_voigt, voigt_to_matrix3

    def stress_now():
        return stress_voigt(_matrix3_to_numpy(utils.getStress()))

    p, k, dt = spec.pressure, spec.servo_interval, O.dt
    B, C = _servo_basis(spec)
    target = C @ (-p * np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0]))
    eng = np.array([1.0, 1.0, 1.0, 2.0, 2.0, 2.0])
    fixed = np.zeros(6)
    fixed[2] = -spec.strain_rate  # the prescribed part of the strain rate
    rate = fixed.copy()
    drift = np.zeros(len(C))
    s_prev, D = stress_and_tangent(utils)
    e_prev = _cell_strain(O)
    errors, n_update, stops = [], 0, 0
    next_stop = spec.stop_every if spec.stop_every > 0 else math.inf
    record("start")
    step = O.step
    while True:
        # rates of the next interval: remove servo_gain of the error, and the drift the
        # tangent does not predict (sliding, rearrangement), learned from the last intervals
        want = spec.servo_gain * (target - C @ s_prev) - drift
        CDB = C @ D @ (eng[:, None] * B)
        x = np.linalg.solve(CDB, want - C @ D @ (fixed * k * dt * eng)) / (k * dt)
        rate = fixed + B @ np.clip(x, -spec.max_lateral_rate, spec.max_lateral_rate)
        O.cell.velGrad = voigt_to_matrix3(rate, Matrix3)
        for _ in range(k):
            step()
        n_update += 1
        e_now = _cell_strain(O)
        if n_update % spec.tangent_every == 0:
            s_now, D_new = stress_and_tangent(utils)
        else:
            s_now, D_new = stress_now(), None
        observed = C @ (s_now - s_prev)
        predicted = C @ (D @ ((e_now - e_prev) * eng))
        drift = (1 - spec.servo_memory) * drift + spec.servo_memory * (observed - predicted)
        if D_new is not None:
            D = D_new
        s_prev, e_prev = s_now, e_now
        axial = -e_now[2]
        if axial > 1e-4:  # after the first 0.01 %: lateral normal stresses (and shear, if free) vs the goal
            held = [0, 1] + ([3, 4, 5] if spec.shear == "free" else [])
            goal = -p * np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])
            errors.append(float(np.abs(s_now[held] - goal[held]).max() / p))
        if n_update % spec.record_every == 0 or axial >= spec.axial_strain:
            record()
        if axial >= spec.axial_strain:
            break
        if axial >= next_stop:
            O.cell.velGrad = Matrix3.Zero
            for _ in range(spec.stop_steps):
                step()
            stops += 1
            while next_stop <= axial:
                next_stop += spec.stop_every
            s_prev, e_prev = stress_now(), _cell_strain(O)  # the next rates start from the state after the stop
            record("stop")
    O.cell.velGrad = Matrix3.Zero
    errors = np.asarray(errors) if errors else np.zeros(1)
    return {"servo_updates": n_update, "stops": stops, "servo_error_max": float(errors.max()),
            "servo_error_p99": float(np.quantile(errors, 0.99)), "servo_error_mean": float(errors.mean())}


def _replay(O, spec: DirectSpec, record: _Recorder) -> dict:
    from yade.minieigenHP import Matrix3

    from ..dem.rve import voigt_to_matrix3
    from ..dem.worker import steps_for_increment

    increments = np.asarray(spec.replay_dstrain, dtype=float).reshape(-1, 6)
    record("start")
    step = O.step
    total = 0
    for d in increments:
        n = steps_for_increment(d, O.dt, spec.replay_rate, spec.min_steps, spec.max_steps)
        if n == 0:
            record()
            continue
        # as Host.impose, line by line (with stops)
        O.cell.velGrad = voigt_to_matrix3(d / (n * O.dt), Matrix3)
        for _ in range(n):
            step()
        total += n
        if spec.replay_stops:
            O.cell.velGrad = Matrix3.Zero
            for _ in range(spec.stop_steps):
                step()
            total += spec.stop_steps
        record()
    if not spec.replay_stops:  # settle the last increment's pending cell update, then stop
        O.cell.velGrad = Matrix3.Zero
        step()
        record("end")
    return {"increments": len(increments), "steps": total}


def _peri_triax(O, spec: DirectSpec, record: _Recorder) -> dict:
    """YADE's own PeriTriaxController: σ11, σ22 stress-controlled (stressMask 3), ε33 at
    maxStrainRate toward a goal beyond the end; quasi-static gain, or a cell mass (dyn_cell)."""
    from yade import utils
    from yade.wrapper import PeriTriaxController

    from ..dem.rve import _matrix3_to_numpy, stress_voigt

    p = spec.pressure
    z0 = math.log(O.cell.trsf[2, 2])  # its strains are log(trsf_ii), consolidation included
    ctrl = PeriTriaxController(
        goal=(-p, -p, z0 - spec.axial_strain - 0.01), stressMask=3, relStressTol=2.5e-3, absStressTol=0.0,
        maxStrainRate=(spec.max_lateral_rate, spec.max_lateral_rate, spec.strain_rate), dynCell=spec.dyn_cell,
        maxUnbalanced=0.0, label="direct_triax")
    engines = list(O.engines)
    at = next(i for i, e in enumerate(engines) if type(e).__name__ == "NewtonIntegrator")
    O.engines = engines[:at] + [ctrl] + engines[at:]
    record("start")
    errors = []
    while True:
        for _ in range(spec.servo_interval):
            O.step()
        s = stress_voigt(_matrix3_to_numpy(utils.getStress()))
        row = record()
        if row["axial_strain"] > 1e-4:
            errors.append(float(np.abs(s[:2] + p).max() / p))
        if row["axial_strain"] >= spec.axial_strain:
            break
    O.engines = engines
    errors = np.asarray(errors) if errors else np.zeros(1)
    return {"servo_error_max": float(errors.max()), "servo_error_p99": float(np.quantile(errors, 0.99)),
            "servo_error_mean": float(errors.mean())}


def run_in_yade(spec: DirectSpec, packing: str) -> dict:
    """Run one direct test in the current (YADE) process."""
    from yade import utils
    from yade.wrapper import Omega

    spec.check()
    O = Omega()
    t0, c0 = time.perf_counter(), time.process_time()
    _load(O, str(packing), spec.damping, spec.homo_deform)
    O.dt = O.dt * float(spec.dt_factor)
    it0 = O.iter
    record = _Recorder(O, utils)
    info = {"servo": _servo, "replay": _replay, "peri_triax": _peri_triax}[spec.mode](O, spec, record)
    steps = int(O.iter - it0)
    out = {
        "spec": {k: v for k, v in asdict(spec).items() if k != "replay_dstrain"},
        "n_replay_increments": len(spec.replay_dstrain),
        "packing": str(packing),
        "n_spheres": len(O.bodies),
        "dt": float(O.dt),
        "dem_steps": steps,
        "wall_time": time.perf_counter() - t0,
        "cpu_time": time.process_time() - c0,
        "records": record.rows,
        **info,
    }
    return out


def main(argv: list[str]) -> int:
    spec_path, packing_path, result_path = argv
    from ..dem.yade_env import import_yade

    import_yade()
    spec = DirectSpec(**json.loads(Path(spec_path).read_text()))
    result = run_in_yade(spec, packing_path)
    tmp = f"{result_path}.tmp{os.getpid()}"
    Path(tmp).write_text(json.dumps(result))
    os.replace(tmp, result_path)
    return 0


# --------------------------------------------------------------------------- caller side


def run_direct(spec: DirectSpec, packing: str | Path, timeout: float | None = None) -> dict:
    """One direct test in a fresh YADE process; returns its result dict (records, timing)."""
    from tempfile import TemporaryDirectory

    from ..dem.yade_env import child_env

    spec.check()
    with TemporaryDirectory() as tmp:
        spec_file, result_file = Path(tmp) / "spec.json", Path(tmp) / "result.json"
        spec_file.write_text(json.dumps(asdict(spec)))
        cmd = [sys.executable, "-m", "granular_multiscale.studies.direct_triaxial", str(spec_file), str(packing),
               str(result_file)]
        proc = subprocess.run(cmd, env=child_env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                              timeout=timeout)
        if proc.returncode != 0:
            raise RuntimeError(f"direct triaxial test ({spec.mode}) on {packing} failed:\n{proc.stderr[-4000:]}")
        return json.loads(result_file.read_text())


def fem_dem_config(n_steps: int = 45, axial_strain: float = 0.045, tolerance: float = 1e-3,
                   dem: dict | None = None, newton: dict | None = None) -> dict:
    """The reference FEM–DEM setting: uniform field, smooth platens, one monotonic segment,
    dem.newton.tolerance, the study's strain rate (other keys: the defaults, or ``dem`` /
    ``dem.newton`` overrides)."""
    from ..config import validate_config

    return validate_config({
        "specimen": {"platen": "smooth", "uniform_field": True},
        "dem": {"strain_rate": STUDY_STRAIN_RATE, **(dem or {}), "newton": {"tolerance": tolerance, **(newton or {})}},
        "load_paths": {"mono": {"segments": [[int(n_steps), float(axial_strain)]]}},
        "training_path": "mono", "validation_path": "mono",
    })


def increments_of(result: dict, every: float | None = None) -> list:
    """Strain increments of a run, for a replay: a FEM–DEM result's committed increments
    (exactly what its RVE got), or a direct result's cell strain sampled every ``every`` of
    axial strain (its own records if None)."""
    if "dstrain" in result:
        return np.asarray(result["dstrain"]).tolist()
    rows = result["records"]
    a = np.array([r["axial_strain"] for r in rows])
    e = np.array([r["strain"] for r in rows])
    if every is not None:
        targets = np.arange(every, a.max() + 1e-12, every)
        e = np.array([[np.interp(t, a, e[:, c]) for c in range(6)] for t in targets])
        e = np.vstack([np.zeros(6), e])
    return np.diff(e, axis=0).tolist()


def curve(result: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(axial strain, q, εv) of a direct result or a FEM–DEM result, in order of axial strain."""
    if "records" in result:
        rows = result["records"]
        a = np.array([r["axial_strain"] for r in rows])
        q = np.array([r["q"] for r in rows])
        v = np.array([r["volumetric_strain"] for r in rows])
    else:
        a, q, v = (np.asarray(result[k]) for k in ("axial_strain", "q", "volumetric_strain"))
    order = np.argsort(a, kind="stable")
    return a[order], q[order], v[order]


def at_strains(result: dict, points=REPORT_AT) -> dict:
    """q (Pa) and εv at the given axial strains (linear interpolation between records)."""
    a, q, v = curve(result)
    pts = np.asarray(points, dtype=float)
    if pts.max() > a.max() + 1e-9:
        raise ValueError(f"the run reached axial strain {a.max():.5f}, not {pts.max():.5f}")
    return {"axial_strain": pts.tolist(), "q": np.interp(pts, a, q).tolist(), "volumetric_strain": np.interp(pts, a, v).tolist()}


def peak(result: dict) -> tuple[float, float]:
    """(axial strain, q) at the largest q of a run."""
    a, q, _ = curve(result)
    i = int(np.argmax(q))
    return float(a[i]), float(q[i])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
