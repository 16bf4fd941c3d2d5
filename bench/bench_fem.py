"""Benchmark of the FEM core at the paper mesh (5×5×10 hexahedra, 2000 Gauss points) with
the elastoplastic model: cost of one Newton iteration split into material / assembly /
solve, the whole Path2 run, and why assembly does not use scikit-fem's BilinearForm.
The run-time options (quarter symmetry, modified Newton) on the same run. With --fem-ml, the
split for FEM–ML: NNσ + ND (tangent nn) and NNσ with its autodiff tangent at every Gauss
point (paper architecture 4×20, trained briefly on the elastoplastic reference: a forward
pass costs the same whatever the weights, the solve depends on the tangent). The whole
FEM–ML run at this mesh, with iteration counts: bench/bench_fem_ml.py.

    .venv/bin/python bench/bench_fem.py [--elements 5 5 10] [--repeat 20] [--fem-ml] [--configfile FILE ...] [--out FILE]

Printed, and written to the record (--out, default {output_dir}/bench/fem.json): the mesh, the
Newton iteration's split (``iteration_ms``), the BilinearForm comparison, the Path2 run
(``path2``), each option against it (``options``: wall time, speedup, top-force difference in %
of the full run's peak) and, with --fem-ml, the FEM–ML split per tangent (``fem_ml``). The
problem and the networks' architecture are the paper's whatever the config; --configfile only
says where the record goes.
"""

from __future__ import annotations

import time

import numpy as np
from skfem import BilinearForm
from skfem.helpers import sym_grad

from granular_multiscale.fem.newton import NewtonSettings
from granular_multiscale.fem.triaxial import TriaxialProblem
from granular_multiscale.materials import Elastoplastic
from granular_multiscale.paths import LoadPath

from common import bench_parser, surrogate_models, top_force_error_pct

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


def main(argv=None) -> dict:
    parser = bench_parser("fem", __doc__)
    parser.add_argument("--elements", type=int, nargs=3, default=[5, 5, 10])
    parser.add_argument("--repeat", type=int, default=20)
    parser.add_argument("--fem-ml", action="store_true", help="also time FEM–ML (networks at the Gauss points)")
    args = parser.parse_args(argv)
    measurement = parser.measurement(args)

    t0 = time.perf_counter()
    problem = TriaxialProblem(size=(0.5, 0.5, 1.0), elements=tuple(args.elements), platen="rough")
    setup = time.perf_counter() - t0
    n_gp, n_dofs = problem.n_gauss_points, problem.ops.n_dofs
    print(f"mesh {args.elements} : {problem.n_elements} elements, {n_gp} Gauss points, {n_dofs} dofs; "
          f"setup {1e3 * setup:.0f} ms")
    figures = {"elements": problem.n_elements, "gauss_points": n_gp, "dofs": n_dofs, "setup_ms": 1e3 * setup}

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
    plastic = float(material._last_plastic.mean())
    print(f"plastic points in the trial: {plastic:.0%}")

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
    figures.update({"plastic_share_of_the_trial": plastic,
                    "iteration_ms": {"material": t_material, "assembly": t_assembly, "strain": t_strain,
                                     "internal_force": t_force, "stiffness": t_stiff, "solve": t_solve, "total": total},
                    "bilinear_form_stiffness_ms": t_bilinear, "bilinear_form_relative_difference": float(agree)})

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
    figures["path2"] = {"steps": PATH2.n_steps, "wall_s": wall, "newton_corrections": int(a["total_newton_corrections"]),
                        "material_evaluations": int(evaluations), "cutbacks": int(ds.cutbacks.sum()),
                        "material_s": float(a["time_material_s"]), "assembly_s": float(a["time_assembly_s"]),
                        "solve_s": float(a["time_solve_s"]), "ms_per_evaluation": 1e3 * wall / evaluations,
                        "deviator_kpa_at_0.9_pct": q[9] / 1e3, "deviator_kpa_at_4.5_pct": q[-1] / 1e3}

    # the scene options on the same run
    figures["options"] = {}
    for label, kwargs in (("quarter symmetry", dict(symmetry="quarter")),
                          ("modified Newton (tangent every 3)", dict(newton=NewtonSettings(tangent_every=3)))):
        other = TriaxialProblem(size=(0.5, 0.5, 1.0), elements=tuple(args.elements), platen="rough", **kwargs)
        t0 = time.perf_counter()
        ds_o = other.run(Elastoplastic(other.n_gauss_points, initial_stress=other.initial_stress), PATH2,
                         progress=False)
        wall_o = time.perf_counter() - t0
        difference = top_force_error_pct(ds, ds_o)
        print(f"  {label:34s} {wall_o:6.2f} s ({wall / wall_o:.1f}x faster), {other.n_gauss_points} Gauss points, "
              f"{ds_o.attrs['total_tangent_evaluations']} tangent evaluations "
              f"(full: {a['total_tangent_evaluations']}), top force within {difference:.1e} % of the peak")
        figures["options"][label] = {"wall_s": wall_o, "speedup": wall / wall_o, "gauss_points": other.n_gauss_points,
                                     "tangent_evaluations": int(ds_o.attrs["total_tangent_evaluations"]),
                                     "top_force_error_pct": difference}
    figures["path2"]["tangent_evaluations"] = int(a["total_tangent_evaluations"])

    if args.fem_ml:
        figures["fem_ml"] = bench_fem_ml(problem, u, strain, args.repeat)
    measurement.finish(figures, args.out)
    print(f"wrote {args.out}")
    return figures


def bench_fem_ml(problem, u, strain, repeat: int) -> dict:
    """Seconds per FEM–ML Newton iteration at the same trial state: network / assembly / solve."""
    import torch

    from granular_multiscale.config import validate_config
    from granular_multiscale.surrogate.material import SurrogateMaterial
    from granular_multiscale.surrogate.models import SurrogateModel

    torch.set_num_threads(1)
    config = validate_config({"reference_material": "elastoplastic"})  # the paper's architecture
    settings = config["surrogate"]
    # networks trained briefly on the elastoplastic reference (common.surrogate_models):
    # a forward pass costs the same whatever the weights, but the solve depends on the tangent
    small = TriaxialProblem(size=(0.5, 0.5, 1.0), elements=(2, 2, 4))
    sigma_path, tangent_path, note = surrogate_models(config, None, small, None)
    nets = {"sigma": SurrogateModel.load(sigma_path), "tangent": SurrogateModel.load(tangent_path)}
    print(f"FEM–ML networks {note}")
    figures = {"networks": note}
    n_gp = problem.n_gauss_points
    print(f"FEM–ML, one Newton iteration at {n_gp} Gauss points (median of {repeat}; torch {torch.__version__}, "
          f"1 thread, float64, {settings['hidden_layers']}x{settings['hidden_units']} {settings['activation']}):")
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
        print(f"  tangent {tangent:8s} network {t_net:7.2f} ms (stress only {t_net_stress:.2f})  assembly {t_assembly:6.2f} ms"
              f"  solve {t_solve:6.2f} ms  total {total:7.2f} ms = {1e-3 * total:.4f} s "
              f"(network {t_net / total:.0%}, assembly {t_assembly / total:.0%}, solve {t_solve / total:.0%})")
        figures[tangent] = {"network_ms": t_net, "network_stress_only_ms": t_net_stress, "assembly_ms": t_assembly,
                            "solve_ms": t_solve, "total_ms": total}
    return figures


if __name__ == "__main__":
    main()
