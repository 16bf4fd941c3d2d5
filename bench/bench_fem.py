"""Benchmark of the FEM core at the paper mesh (5×5×10 hexahedra, 2000 Gauss points) with
the elastoplastic model: cost of one Newton iteration split into material / assembly /
solve, the whole Path2 run, and why assembly does not use scikit-fem's BilinearForm.
The run-time options (quarter symmetry, modified Newton) on the same run. With --fem-ml, the
split for FEM–ML: NNσ + ND (tangent nn) and NNσ with its autodiff tangent at every Gauss
point (paper architecture 4×20, trained briefly on the elastoplastic reference: a forward
pass costs the same whatever the weights, the solve depends on the tangent). The whole
FEM–ML run at this mesh, with iteration counts: bench/bench_fem_ml.py.

    .venv/bin/python bench/bench_fem.py [--elements 5 5 10] [--repeat 20] [--fem-ml]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from skfem import BilinearForm
from skfem.helpers import sym_grad

from granular_multiscale.fem.newton import NewtonSettings
from granular_multiscale.fem.triaxial import TriaxialProblem
from granular_multiscale.materials import Elastoplastic
from granular_multiscale.paths import LoadPath

PATH2 = LoadPath("path2", ((9, 0.009), (6, 0.003), (42, 0.045)))


def best_ms(fn, repeat):
    """Median wall time of fn() in ms (median: the machine is shared)."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def _engineering(e):
    return [e[0, 0], e[1, 1], e[2, 2], 2 * e[1, 2], 2 * e[0, 2], 2 * e[0, 1]]


@BilinearForm
def tangent_form(u, v, w):
    """K = ∫ ε_eng(v) · D ε_eng(u) with a per-point 6×6 D, the scikit-fem way."""
    eu, ev = _engineering(sym_grad(u)), _engineering(sym_grad(v))
    D = w["D"]
    return sum(ev[i] * D[i, j] * eu[j] for i in range(6) for j in range(6))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--elements", type=int, nargs=3, default=[5, 5, 10])
    parser.add_argument("--repeat", type=int, default=20)
    parser.add_argument("--fem-ml", action="store_true", help="also time FEM–ML (networks at the Gauss points)")
    args = parser.parse_args()

    t0 = time.perf_counter()
    problem = TriaxialProblem(size=(0.5, 0.5, 1.0), elements=tuple(args.elements), platen="rough")
    setup = time.perf_counter() - t0
    n_gp, n_dofs = problem.n_gauss_points, problem.ops.n_dofs
    print(f"mesh {args.elements} : {problem.n_elements} elements, {n_gp} Gauss points, {n_dofs} dofs; "
          f"setup {1e3 * setup:.0f} ms")

    # one Newton iteration at a representative plastic state (1 % axial strain, mid loading)
    material = Elastoplastic(n_gp, initial_stress=problem.initial_stress)
    ds = problem.run(material, LoadPath("to1pct", ((10, 0.01),)), progress=False)
    u = np.zeros(n_dofs)
    u[problem.ops.basis.nodal_dofs] = ds.displacement.values[-1].T
    u[problem.system.free] *= 1.001  # a trial state near, not at, equilibrium
    strain = problem.ops.strain(u)
    stress, tangent = material.evaluate(strain)
    K_data = problem.ops.stiffness_data(tangent)
    residual = problem.ops.internal_force(stress) - problem.f_ext
    print(f"plastic points in the trial: {material._last_plastic.mean():.0%}")

    t_material = best_ms(lambda: material.evaluate(strain, need_tangent=True), args.repeat)
    t_strain = best_ms(lambda: problem.ops.strain(u), args.repeat)
    t_force = best_ms(lambda: problem.ops.internal_force(stress), args.repeat)
    t_stiff = best_ms(lambda: problem.ops.stiffness_data(tangent), args.repeat)
    t_solve = best_ms(lambda: problem.system.solve(K_data, -residual), args.repeat)
    t_assembly = t_strain + t_force + t_stiff
    total = t_material + t_assembly + t_solve
    print("one Newton iteration (median of %d):" % args.repeat)
    print(f"  material (evaluate + tangent)   {t_material:7.2f} ms")
    print(f"  assembly                        {t_assembly:7.2f} ms  "
          f"(strain {t_strain:.2f}, internal force {t_force:.2f}, stiffness {t_stiff:.2f})")
    print(f"  solve (SuperLU)                 {t_solve:7.2f} ms")
    print(f"  total                           {total:7.2f} ms   (target < 50 ms)")

    # the same stiffness through scikit-fem's BilinearForm, for comparison
    D_field = np.ascontiguousarray(tangent.reshape(problem.n_elements, 8, 6, 6).transpose(2, 3, 0, 1))
    K_skfem = tangent_form.assemble(problem.ops.basis, D=D_field)
    K_ours = problem.ops.csr(K_data)
    agree = abs(K_skfem - K_ours).max() / abs(K_ours).max()
    t_bilinear = best_ms(lambda: tangent_form.assemble(problem.ops.basis, D=D_field), max(3, args.repeat // 4))
    print(f"  (scikit-fem BilinearForm stiffness: {t_bilinear:.1f} ms, {t_bilinear / t_stiff:.0f}x ours; "
          f"same matrix to {agree:.1e})")

    # the whole Path2 run
    material = Elastoplastic(n_gp, initial_stress=problem.initial_stress)
    t0 = time.perf_counter()
    ds = problem.run(material, PATH2, progress=False)
    wall = time.perf_counter() - t0
    a = ds.attrs
    evaluations = a["total_material_evaluations"]
    print(f"Path2 ({PATH2.n_steps} steps): {wall:.2f} s wall (target < 30 s); "
          f"{a['total_newton_corrections']} Newton corrections, {evaluations} material evaluations, "
          f"{int(ds.cutbacks.sum())} cutbacks")
    print(f"  split: material {a['time_material_s']:.2f} s, assembly {a['time_assembly_s']:.2f} s, "
          f"solve {a['time_solve_s']:.2f} s (includes one predictor solve per step); "
          f"{1e3 * wall / evaluations:.1f} ms per evaluation overall")
    q = -ds.top_force.values / (0.5 * 0.5) - problem.confining_pressure
    print(f"  deviator at 0.9 % / 4.5 %: {q[9] / 1e3:.0f} / {q[-1] / 1e3:.0f} kPa")

    # the scene options on the same run
    for label, kwargs in (("quarter symmetry", dict(symmetry="quarter")),
                          ("modified Newton (tangent every 3)", dict(newton=NewtonSettings(tangent_every=3)))):
        other = TriaxialProblem(size=(0.5, 0.5, 1.0), elements=tuple(args.elements), platen="rough", **kwargs)
        t0 = time.perf_counter()
        ds_o = other.run(Elastoplastic(other.n_gauss_points, initial_stress=other.initial_stress), PATH2,
                         progress=False)
        wall_o = time.perf_counter() - t0
        diff = np.abs(ds_o.top_force.values - ds.top_force.values).max() / np.abs(ds.top_force.values).max()
        print(f"  {label:34s} {wall_o:6.2f} s ({wall / wall_o:.1f}x faster), {other.n_gauss_points} Gauss points, "
              f"{ds_o.attrs['total_tangent_evaluations']} tangent evaluations "
              f"(full: {a['total_tangent_evaluations']}), top force within {diff:.1e}")

    if args.fem_ml:
        bench_fem_ml(problem, u, strain, args.repeat)


def bench_fem_ml(problem, u, strain, repeat: int) -> None:
    """Seconds per FEM–ML Newton iteration at the same trial state: network / assembly / solve."""
    import torch

    from granular_multiscale.config import validate_config
    from granular_multiscale.surrogate.material import SurrogateMaterial
    from granular_multiscale.surrogate.models import SurrogateModel

    torch.set_num_threads(1)
    config = validate_config({"reference_material": "elastoplastic"})
    settings = config["surrogate"]
    # networks trained briefly on the elastoplastic reference (common.surrogate_models):
    # a forward pass costs the same whatever the weights, but the solve depends on the tangent
    from common import surrogate_models

    small = TriaxialProblem(size=(0.5, 0.5, 1.0), elements=(2, 2, 4))
    sigma_path, tangent_path, note = surrogate_models(config, None, small, None)
    nets = {"sigma": SurrogateModel.load(sigma_path), "tangent": SurrogateModel.load(tangent_path)}
    print(f"FEM–ML networks {note}")
    n_gp = problem.n_gauss_points
    print(f"FEM–ML, one Newton iteration at {n_gp} Gauss points (median of {repeat}; torch {torch.__version__}, "
          f"1 thread, float64, {settings['hidden_layers']}x{settings['hidden_units']} {settings['activation']}):")
    t_assembly_parts = []
    for tangent in ("nn", "autodiff"):
        material = SurrogateMaterial(n_gp, nets["sigma"], nets["tangent"], tangent)
        stress, D = material.evaluate(strain)
        K_data = problem.ops.stiffness_data(D)
        residual = problem.ops.internal_force(stress) - problem.f_ext
        t_net = best_ms(lambda: material.evaluate(strain, need_tangent=True), repeat)
        t_net_stress = best_ms(lambda: material.evaluate(strain, need_tangent=False), repeat)
        t_assembly = (best_ms(lambda: problem.ops.strain(u), repeat) + best_ms(lambda: problem.ops.internal_force(stress), repeat)
                      + best_ms(lambda: problem.ops.stiffness_data(D), repeat))
        t_solve = best_ms(lambda: problem.system.solve(K_data, -residual), repeat)
        total = t_net + t_assembly + t_solve
        t_assembly_parts.append(t_assembly)
        print(f"  tangent {tangent:8s} network {t_net:7.2f} ms (stress only {t_net_stress:.2f})  assembly {t_assembly:6.2f} ms"
              f"  solve {t_solve:6.2f} ms  total {total:7.2f} ms = {1e-3 * total:.4f} s "
              f"(network {t_net / total:.0%}, assembly {t_assembly / total:.0%}, solve {t_solve / total:.0%})")


if __name__ == "__main__":
    main()
