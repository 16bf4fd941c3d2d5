"""FEM core: patch test, closed-form elastic specimen, equilibrium, stiffness symmetry."""

import numpy as np
import pytest

from granular_multiscale.fem.assembly import GaussPointOperators
from granular_multiscale.fem.mesh import box_mesh
from granular_multiscale.fem.newton import DirichletSystem, NewtonSettings, Timers, newton_solve
from granular_multiscale.fem.triaxial import TriaxialProblem
from granular_multiscale.materials import Elastoplastic, LinearElastic
from granular_multiscale.paths import LoadPath
from granular_multiscale.tensors import tensor_to_voigt

P0 = 1.0e5


def test_gauss_points_and_numbering():
    problem = TriaxialProblem(size=(0.4, 0.6, 1.2), elements=(2, 3, 4))
    assert problem.n_gauss_points == 2 * 3 * 4 * 8
    gp = problem.gp_positions
    # gp = element * 8 + q: the 8 points of an element surround its centroid, ±h/(2√3) away
    centroids = problem.mesh.p[:, problem.mesh.t].mean(axis=1).T
    np.testing.assert_allclose(gp.reshape(-1, 8, 3).mean(axis=1), centroids, atol=1e-12)
    offsets = np.abs(gp.reshape(-1, 8, 3) - centroids[:, None, :])
    np.testing.assert_allclose(offsets, np.broadcast_to([0.2, 0.2, 0.3], offsets.shape) / (2 * np.sqrt(3)))
    # quadrature weights sum to the volume
    assert problem.ops.dV.sum() == pytest.approx(0.4 * 0.6 * 1.2, rel=1e-13)


def _distorted_ops():
    mesh = box_mesh((1.0, 1.0, 1.0), (2, 2, 2))
    centre = np.argmin(np.linalg.norm(mesh.p.T - 0.5, axis=1))
    mesh.p[:, centre] += [0.11, -0.07, 0.05]  # an irregular interior node: elements are not boxes
    return GaussPointOperators(mesh)


def test_patch_test_linear_field_gives_exact_homogeneous_strain():
    ops = _distorted_ops()
    grad = np.array([[1.0, 0.3, -0.2], [0.5, -2.0, 0.4], [0.1, 0.7, 0.6]]) * 1e-3  # incl. rotation
    x = ops.mesh.p
    u = np.zeros(ops.n_dofs)
    u[ops.basis.nodal_dofs] = grad @ x
    expected = tensor_to_voigt(grad)
    np.testing.assert_allclose(ops.strain(u), np.broadcast_to(expected, (ops.n_gauss_points, 6)), atol=1e-16)


def test_patch_test_solved_interior_reproduces_homogeneous_state():
    """Boundary nodes follow a linear field; the solver must find it in the interior."""
    ops = _distorted_ops()
    x = ops.mesh.p
    boundary = np.flatnonzero(np.any((np.abs(x) < 1e-12) | (np.abs(x - 1) < 1e-12), axis=0))
    grad = np.array([[2.0, 0.4, 0.0], [0.4, -1.0, 0.3], [0.0, 0.3, -3.0]]) * 1e-3
    u_exact = np.zeros(ops.n_dofs)
    u_exact[ops.basis.nodal_dofs] = grad @ x
    constrained = ops.basis.nodal_dofs[:, boundary].ravel()
    system = DirichletSystem(ops, constrained)
    material = LinearElastic(ops.n_gauss_points, 5e7, 0.3)
    result = newton_solve(ops, system, material, np.zeros(ops.n_dofs), np.zeros(ops.n_dofs),
                          u_exact[system.constrained], NewtonSettings(tolerance=1e-12), None, Timers())
    np.testing.assert_allclose(result.u, u_exact, atol=1e-15)
    stress = material.evaluate(ops.strain(u_exact))[0][0]
    np.testing.assert_allclose(result.stress, np.broadcast_to(stress, result.stress.shape), rtol=1e-9, atol=1e-6)


def test_linear_elastic_smooth_platens_against_closed_form():
    E, nu, eps = 4.0e7, 0.3, 2.0e-3
    problem = TriaxialProblem(size=(0.3, 0.5, 0.8), elements=(2, 3, 3), platen="smooth")
    material = LinearElastic(problem.n_gauss_points, E, nu, initial_stress=problem.initial_stress)
    ds = problem.run(material, LoadPath("p", ((4, eps),)), progress=False)
    last = ds.isel(step=-1)
    sigma_expected = np.array([-P0, -P0, -P0 - E * eps, 0, 0, 0])
    strain_expected = np.array([nu * eps, nu * eps, -eps, 0, 0, 0])
    np.testing.assert_allclose(last.stress.values, np.broadcast_to(sigma_expected, (problem.n_gauss_points, 6)),
                               rtol=0, atol=1e-6 * P0)
    np.testing.assert_allclose(last.strain.values, np.broadcast_to(strain_expected, (problem.n_gauss_points, 6)),
                               rtol=0, atol=1e-12)
    area = 0.3 * 0.5
    np.testing.assert_allclose(ds.top_force.values, -(P0 + E * ds.axial_strain.values) * area, rtol=1e-10)
    np.testing.assert_allclose(ds.volumetric_strain.values, -(1 - 2 * nu) * ds.axial_strain.values, atol=1e-14)
    # nodal displacements of the homogeneous field ux = ν ε x, uz = −ε z
    x = ds.node_position.values
    np.testing.assert_allclose(last.displacement.values[:, 0], nu * eps * x[:, 0], atol=1e-14)
    np.testing.assert_allclose(last.displacement.values[:, 2], -eps * x[:, 2], atol=1e-14)
    assert ds.top_force.values[0] == pytest.approx(-P0 * area)  # step 0: the consolidated state


def test_top_reaction_equals_integral_of_sigma_zz_and_global_equilibrium():
    """Rough platens + elastoplastic: a non-uniform field. The platen reaction equals
    (1/h)∫ σzz dV over the top element layer (the weak form of ∫σzz dA on the top face),
    and the top and bottom axial reactions cancel (the confinement has no axial part)."""
    problem = TriaxialProblem(size=(0.5, 0.5, 1.0), elements=(2, 2, 4), platen="rough")
    material = Elastoplastic(problem.n_gauss_points, initial_stress=problem.initial_stress)
    ds = problem.run(material, LoadPath("p", ((6, 0.012),)), progress=False)
    stress = ds.stress.isel(step=-1).values
    assert np.ptp(stress[:, 2]) > 0.05 * P0, "the field should not be homogeneous with rough platens"
    h = 1.0 / 4
    gp_z = problem.gp_positions[:, 2]
    top_layer = gp_z > 1.0 - h
    integral = np.sum(problem.ops.dV.ravel()[top_layer] * stress[top_layer, 2]) / h
    assert ds.top_force.values[-1] == pytest.approx(integral, rel=1e-10)
    residual = problem.ops.internal_force(stress) - problem.f_ext
    bottom_z = problem.ops.node_dofs(problem.faces["bottom"], 2)
    assert residual[bottom_z].sum() == pytest.approx(-ds.top_force.values[-1], rel=1e-9)
    assert np.linalg.norm(residual[problem.system.free]) < 1e-8 * np.linalg.norm(residual[problem.system.constrained])
    # and a lateral confinement that balances: Σ f_ext = 0, each face carries p0 × its area
    assert np.abs(problem.f_ext.reshape(-1, 3).sum(axis=0)).max() < 1e-9
    assert problem.f_ext.reshape(-1, 3)[problem.faces["xmax"], 0].sum() == pytest.approx(-P0 * 0.5 * 1.0)


def test_stiffness_is_symmetric_for_symmetric_tangents_and_has_rigid_modes():
    ops = _distorted_ops()
    rng = np.random.default_rng(3)
    A = rng.normal(size=(ops.n_gauss_points, 6, 6))
    D = A @ np.swapaxes(A, 1, 2) * 1e7  # symmetric positive definite per point
    K = ops.stiffness(D)
    assert abs(K - K.T).max() <= 1e-12 * abs(K).max()
    # rigid translations and an infinitesimal rotation produce no force
    x = ops.mesh.p
    for field in (np.array([[1.0], [0.0], [0.0]]) + 0 * x, np.array([-x[1], x[0], 0 * x[2]])):
        u = np.zeros(ops.n_dofs)
        u[ops.basis.nodal_dofs] = field
        assert np.abs(K @ u).max() < 1e-9 * abs(K).max()
    # a non-symmetric tangent gives a non-symmetric K (the check above can fail)
    D[:, 0, 1] += 1e7
    K = ops.stiffness(D)
    assert abs(K - K.T).max() > 1e-3 * abs(K).max()


def test_stiffness_matches_scikit_fem_bilinear_form():
    """The einsum/scatter assembly equals scikit-fem's own linear elasticity form."""
    from skfem import BilinearForm
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    ops = _distorted_ops()
    E, nu = 3e7, 0.2
    K_skfem = BilinearForm(linear_elasticity(*lame_parameters(E, nu))).assemble(ops.basis)
    from granular_multiscale.tensors import isotropic_elastic_tangent

    K = ops.stiffness(np.broadcast_to(isotropic_elastic_tangent(E, nu), (ops.n_gauss_points, 6, 6)))
    assert abs(K - K_skfem).max() <= 1e-10 * abs(K_skfem).max()


def test_internal_force_is_the_transpose_of_the_strain_operator():
    ops = _distorted_ops()
    rng = np.random.default_rng(4)
    u = rng.normal(size=ops.n_dofs)
    stress = rng.normal(size=(ops.n_gauss_points, 6))
    # virtual work: f_int · u = Σ dV σ : ε(u)  (shear counted twice)
    eps = ops.strain(u)
    work = np.sum(ops.dV.ravel()[:, None] * stress * eps * np.array([1, 1, 1, 2, 2, 2]))
    assert ops.internal_force(stress) @ u == pytest.approx(work, rel=1e-12)


def test_from_config_reads_specimen_and_newton():
    from granular_multiscale.config import validate_config

    config = validate_config({"specimen": {"elements": [1, 2, 3], "platen": "smooth", "confining_pressure": 2e5},
                              "newton": {"tolerance": 1e-9}})
    problem = TriaxialProblem.from_config(config)
    assert problem.n_gauss_points == 48
    assert problem.platen == "smooth" and problem.newton.tolerance == 1e-9
    np.testing.assert_allclose(problem.initial_stress, [-2e5, -2e5, -2e5, 0, 0, 0])


# -- the tangent in the run file: what the solver used, without loss -------------------------------------
class _LinearSkew:
    """σ = σ0 + D_i · engineering(ε), D_i a known constant per point; not symmetric unless `skew` is 0.

    Odd points are nearly incompressible (ν = 0.45: smallest/largest Mandel eigenvalue 0.07), even
    ones ν = 0.25 (0.4), so an eigenvalue floor of 0.2 repairs the odd ones only."""

    @staticmethod
    def tangents(n, skew=1.0):
        from granular_multiscale.tensors import isotropic_elastic_tangent

        A = np.zeros((6, 6))
        A[0, 2], A[2, 0], A[3, 5], A[1, 4] = 4e6, -3e6, 2e6, 1e6
        return np.stack([isotropic_elastic_tangent(5e7, 0.45 if i % 2 else 0.25) + skew * A for i in range(n)])

    @classmethod
    def make(cls, n, initial_stress, skew=1.0):
        from granular_multiscale.materials.base import MaterialPointSet
        from granular_multiscale.tensors import engineering

        D = cls.tangents(n, skew)

        class Material(MaterialPointSet):
            method = "linear_skew"

            def evaluate(self, strain, need_tangent=True):
                strain = self._check_strain(strain)
                stress = initial_stress + np.einsum("nij,nj->ni", D, engineering(strain))
                return stress, (D.copy() if need_tangent else None)

            def commit(self, strain=None):
                pass

            def get_state(self):
                return {}

            def set_state(self, state):
                pass

        return Material(n)


def _skew_run(tmp_path, skew=1.0, repair="none", floor=1e-3):
    from granular_multiscale.data import read_run, write_run

    problem = TriaxialProblem(elements=(1, 1, 1), platen="smooth",
                              newton=NewtonSettings(tangent_repair=repair, tangent_floor=floor))
    material = _LinearSkew.make(problem.n_gauss_points, problem.initial_stress, skew)
    ds = problem.run(material, LoadPath("p", ((2, 1e-3),)), progress=False)
    return ds, read_run(write_run(ds, tmp_path / "run.h5"))


def test_non_symmetric_tangent_round_trips_whole_through_the_run_file(tmp_path):
    """A tangent that is not symmetric (like FEM–ML's autodiff Jacobian) is stored in all 36 entries;
    the 21-entry `tangent` is the upper triangle of its symmetric part, and the file says so.
    (Formerly the file held only the upper triangle of D: its lower triangle was lost.)"""
    from granular_multiscale.data import run_tangent
    from granular_multiscale.tensors import TCOMP, TCOMP36, tangent_to_upper

    ds, back = _skew_run(tmp_path)
    D = _LinearSkew.tangents(8)
    assert back.attrs["tangent_symmetric"] == 0 and back.attrs["tangent_variable"] == "tangent_full"
    assert back.attrs["tangent_asymmetry"] == pytest.approx(7e6 / D[0].max())  # |A[0,2] - A[2,0]| / max|D| at ν = 0.25
    assert list(back.tcomp36.values) == list(TCOMP36) and list(back.tcomp.values) == list(TCOMP)
    assert TCOMP36[2] == "1133" and TCOMP36[12] == "3311"  # row by row: entry I*6 + J is D[I, J]
    assert back.tangent_full.dims == ("step", "gp", "tcomp36") and back.tangent_full.attrs["units"] == "Pa"
    full = run_tangent(back)
    np.testing.assert_array_equal(full, np.broadcast_to(D, (3, 8, 6, 6)))  # every step, exactly
    assert full[0, 0, 0, 2] == D[0, 0, 2] != D[0, 2, 0] == full[0, 0, 2, 0]
    np.testing.assert_array_equal(back.tangent_full.sel(tcomp36="3311").values, D[None, :, 2, 0].repeat(3, axis=0))
    np.testing.assert_array_equal(back.tangent.values, tangent_to_upper(0.5 * (full + np.swapaxes(full, -1, -2))))
    assert "SYMMETRIC PART" in back.tangent.attrs["description"] and "tangent_full" in back.tangent.attrs["description"]
    assert "as the material set returned it" in back.tangent_full.attrs["description"]
    for name in ds.variables:
        np.testing.assert_array_equal(back[name].values, ds[name].values, err_msg=name)


def test_symmetric_tangent_keeps_the_21_entry_layout(tmp_path):
    from granular_multiscale.data import run_tangent

    _, back = _skew_run(tmp_path, skew=0.0)
    assert "tangent_full" not in back and "tcomp36" not in back.coords
    assert back.attrs["tangent_symmetric"] == 1 and back.attrs["tangent_variable"] == "tangent"
    assert back.attrs["tangent_asymmetry"] == 0.0
    assert "hold all of it" in back.tangent.attrs["description"]
    np.testing.assert_array_equal(run_tangent(back), np.broadcast_to(_LinearSkew.tangents(8, 0.0), (3, 8, 6, 6)))


def test_repaired_tangent_is_the_one_the_file_holds(tmp_path):
    """With newton.tangent_repair the solver uses the repaired tangent: the file holds that one (the
    floored symmetric matrix at repaired points, the material's own, skew part included, elsewhere)
    and its description says so."""
    from granular_multiscale.data import run_tangent
    from granular_multiscale.materials.wrappers import eig_floor

    ds, back = _skew_run(tmp_path, repair="eig_floor", floor=0.2)
    D = _LinearSkew.tangents(8)
    repaired, mask = eig_floor(D, 0.2)
    np.testing.assert_array_equal(mask, np.arange(8) % 2 == 1)  # the odd (ν = 0.45) points only
    np.testing.assert_array_equal(back.tangent_repaired_points.values, 4)
    full = run_tangent(back)
    np.testing.assert_allclose(full, np.broadcast_to(repaired, (3, 8, 6, 6)), rtol=1e-12)  # LAPACK round-off
    np.testing.assert_array_equal(full[:, 0::2], np.broadcast_to(D[0::2], (3, 4, 6, 6)))  # skew part kept
    np.testing.assert_allclose(full[:, 1::2], np.swapaxes(full[:, 1::2], -1, -2), rtol=0, atol=1e-14 * np.abs(full).max())
    assert back.attrs["tangent_symmetric"] == 0
    for name in ("tangent", "tangent_full"):
        description = back[name].attrs["description"]
        assert "after newton.tangent_repair 'eig_floor' (eigenvalue floor 0.2" in description, name
