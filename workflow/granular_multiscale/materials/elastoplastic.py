"""Analytic elastoplastic reference model: Drucker–Prager cone with combined hardening.

A reference whose truth is known (exact, fast, with a consistent tangent) for testing the
solver and the surrogate without YADE. Tension positive stress; p = −tr σ / 3 is the
(compression positive) mean pressure; s = dev σ; ‖·‖ is the tensor norm, and
Q(x) = sqrt(3/2)‖x‖ the von Mises-type magnitude of a deviatoric tensor.

Elasticity (bulk K, shear G from E, ν):      σ = σ_n + K tr(Δε) 1 + 2G dev(Δε) − plastic part

Yield surface (cone around the back-stress α, deviatoric):

    f(σ, α, κ) = Q(s − α) − η p − k(κ) ≤ 0
    k(κ) = k0 + (k∞ − k0)(1 − exp(−κ/κr)) − k_s (1 − exp(−κ/κs))
                                                   isotropic hardening (saturating), softening

With the softening k_s = 0 (the default) k rises monotonically to k∞. With k_s > 0 and
κs > κr the strength first hardens to a peak and then softens to the residual k∞ − k_s. The
residual may be below k0, even negative: that is allowed as long as the yield stress
η p + k(κ) stays positive at the pressures reached (otherwise the return ends beyond the
apex, which raises MaterialPointError, see below).

Flow (Δλ ≥ 0, n̂ = (s − α)/‖s − α‖) from the potential g = Q(s − α) − β p, hardening:

    Δεᵖ = Δλ (sqrt(3/2) n̂ + β/3 1)      deviatoric part + dilatancy β Δλ (tension positive)
    Δα  = (2/3) H_k dev(Δεᵖ) = sqrt(2/3) H_k Δλ n̂  linear kinematic (Prager) hardening
    Δκ  = Δλ = sqrt(2/3) ‖dev Δεᵖ‖                equivalent deviatoric plastic strain

    β = β0 exp(−κ_n/κd)        dilatancy, evaluated at the converged κ_n of the point

By default β0 = η and κd = ∞: β = η, associated flow. A β0 ≠ η (non-associated flow) and/or
a finite κd (dilatancy decaying with plastic strain, towards a critical state of constant
volume) make the flow non-associated. β is explicit within a load step (a function of the
converged κ_n, which is in the state), so the return mapping below stays one scalar
equation and its tangent stays exactly consistent.

Because α only moves the cone, a reversal of loading yields again on the opposite side of
the cone (reverse yielding): unloading–reloading makes a closed hysteresis loop. The
friction η is a constant and the isotropic hardening enters as k(κ) (not through η): with
associated flow (β = η) this keeps the consistent tangent exactly symmetric, so the 21
stored entries hold all of it. With β ≠ η it is not symmetric (all 36 entries are stored).

Return mapping (backward Euler, radial: n̂ = direction of the trial ξ_tr = s_tr − α_n)
reduces to one scalar equation per point, solved by a vectorised Newton iteration over all
plastic points at once. r is strictly decreasing (r' = −h < 0, see below), so the root is
unique; without softening r is also convex and Newton from Δλ = 0 converges monotonically,
with softening (r may be concave) a Newton step that leaves the bracket of the root bisects:

    r(Δλ) = Q(ξ_tr) − η p_tr − k(κ_n + Δλ) − (3G + H_k + K η β) Δλ = 0

    s = s_tr − sqrt(6) G Δλ n̂,   p = p_tr + K β Δλ,   α = α_n + sqrt(2/3) H_k Δλ n̂

Consistent tangent (Voigt, acting on the engineering strain; first index the stress, second
the strain), with b = sqrt(6) G Δλ/‖ξ_tr‖, the yield-side vector v_f = sqrt(6) G n̂ + K η 1,
the flow-side vector v_g = sqrt(6) G n̂ + K β 1 and h = 3G + H_k + K η β + k'(κ_n + Δλ):

    D = K 1⊗1 + 2G(1 − b) I_dev + 2G b n̂⊗n̂ − v_g⊗v_f / h       (dΔλ = v_f·dε / h)

The construction rejects parameter sets for which h could become ≤ 0 for some κ ≥ 0
(a softening steeper than the elastic shear stiffness: the return would have no unique
solution): it requires 3G + H_k + min_β K η β + min_κ k'(κ) > 0, the minimum of K η β
being K η β0 for κd = ∞ and 0 for finite κd.

A trial on the tension side of the apex (Q(ξ) would become negative) is not a state a
confined granular specimen reaches: it raises MaterialPointError naming the points, which
makes the solver cut the step back.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .base import MaterialPointError, MaterialPointSet
from .elastic import initial_stress_array

_ONE = np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])
# tensor inner product of two Voigt vectors with tensorial components
_NORM_WEIGHT = np.array([1.0, 1.0, 1.0, 2.0, 2.0, 2.0])
_I_SYM = np.diag([1.0, 1.0, 1.0, 0.5, 0.5, 0.5])
_I_DEV = _I_SYM - np.outer(_ONE, _ONE) / 3.0
_SQRT6 = np.sqrt(6.0)
_SQRT23 = np.sqrt(2.0 / 3.0)
_SQRT32 = np.sqrt(1.5)

#: defaults (also in the config schema): a least-squares fit to the Gauss-point mean response of
#: the default-scale FEM–DEM Path1 (calibration.py; 400-sphere RVEs under 100 kPa)
DEFAULTS = {
    "youngs_modulus": 1.55e7,
    "poisson_ratio": 0.05,
    "friction": 0.57,
    "initial_hardening": 0.0,
    "saturated_hardening": 1.43e5,
    "hardening_strain": 0.0034,
    "kinematic_modulus": 1.5e6,
    # off: no softening, associated flow (β = η); k_s ≥ 0, κs > 0, β0 ≥ 0 or None (= η), κd > 0 or ∞
    "softening": 0.0,
    "softening_strain": 0.05,
    "dilatancy": None,
    "dilatancy_strain": np.inf,
}

#: a stiff set with a narrow cone (the defaults before the calibration): a triaxial unloading
#: from 0.9 % axial strain yields in reverse, in extension, and closes a hysteresis loop
REVERSE_YIELDING = {
    "youngs_modulus": 5.0e7,
    "poisson_ratio": 0.25,
    "friction": 0.25,
    "initial_hardening": 0.0,
    "saturated_hardening": 1.5e5,
    "hardening_strain": 0.007,
    "kinematic_modulus": 5.0e5,
}

#: a dense-packing stand-in that peaks and softens towards a critical state (shear-band
#: localisation tests without DEM): the DEFAULTS' E with ν = 0.2, hardening to a peak and
#: softening slowly to the residual k∞ − k_s = 100 kPa, no kinematic hardening (it would grow
#: without bound against the softening), dilatancy β0 = 0.4 < η decaying with κd = 0.03.
#: Plane-strain compression under σ_xx = −100 kPa (ε_yy = 0, axial z, 0.05 % steps): peak deviator
#: σ_zz − σ_xx = 344 kPa at 3.45 % axial strain (the default 400-sphere RVE: 415 kPa at 4.5 %),
#: 266 kPa (0.77 × peak) at 10 %; volumetric strain −1.37 % at the peak (elastic compaction),
#: −0.39 % at 10 %, its rate over 8–10 % is 13 % of its largest; κ = 0.10 at 10 %. A faster
#: softening (k_s = 150 kPa over κs = 0.02) snaps back on coarse meshes: Newton then finds no
#: equilibrium past the peak at any cutback (docs/problems.md).
SOFTENING = {
    "youngs_modulus": 1.55e7,
    "poisson_ratio": 0.2,
    "friction": 0.5,
    "initial_hardening": 0.0,
    "saturated_hardening": 2.0e5,
    "hardening_strain": 0.004,
    "kinematic_modulus": 0.0,
    "softening": 1.0e5,
    "softening_strain": 0.05,
    "dilatancy": 0.4,
    "dilatancy_strain": 0.03,
}


def _norm(x: np.ndarray) -> np.ndarray:
    return np.sqrt(np.sum(_NORM_WEIGHT * x * x, axis=-1))


def _split(stress: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Voigt stress -> (deviator s, compression-positive pressure p)."""
    mean = stress[:, :3].mean(axis=1)
    return stress - mean[:, None] * _ONE, -mean


class Elastoplastic(MaterialPointSet):
    method = "elastoplastic"

    def __init__(
        self,
        n_points: int,
        youngs_modulus: float = DEFAULTS["youngs_modulus"],
        poisson_ratio: float = DEFAULTS["poisson_ratio"],
        friction: float = DEFAULTS["friction"],
        initial_hardening: float = DEFAULTS["initial_hardening"],
        saturated_hardening: float = DEFAULTS["saturated_hardening"],
        hardening_strain: float = DEFAULTS["hardening_strain"],
        kinematic_modulus: float = DEFAULTS["kinematic_modulus"],
        softening: float = DEFAULTS["softening"],
        softening_strain: float = DEFAULTS["softening_strain"],
        dilatancy: float | None = DEFAULTS["dilatancy"],
        dilatancy_strain: float | None = DEFAULTS["dilatancy_strain"],
        initial_stress=None,
    ):
        super().__init__(n_points)
        if dilatancy_strain is None:  # a config may spell the constant dilatancy as null
            dilatancy_strain = np.inf
        checks = {
            "youngs_modulus": youngs_modulus > 0,
            "poisson_ratio": 0 <= poisson_ratio < 0.5,
            "friction": friction >= 0,
            "initial_hardening": initial_hardening >= 0,
            "saturated_hardening": saturated_hardening >= initial_hardening,
            "hardening_strain": hardening_strain > 0,
            "kinematic_modulus": kinematic_modulus >= 0,
            "softening": softening >= 0,
            "softening_strain": softening_strain > 0,
            "dilatancy": dilatancy is None or dilatancy >= 0,
            "dilatancy_strain": dilatancy_strain > 0,
        }
        for key, ok in checks.items():
            if not ok:
                raise ValueError(f"elastoplastic.{key}: invalid value {locals()[key]!r} (see the config schema)")
        E, nu = float(youngs_modulus), float(poisson_ratio)
        self.bulk = E / (3 * (1 - 2 * nu))
        self.shear = E / (2 * (1 + nu))
        self.friction = float(friction)
        self.k0 = float(initial_hardening)
        self.k_inf = float(saturated_hardening)
        self.kappa_ref = float(hardening_strain)
        self.kinematic = float(kinematic_modulus)
        self.k_soft = float(softening)
        self.kappa_soft = float(softening_strain)
        self.dilatancy0 = self.friction if dilatancy is None else float(dilatancy)
        self.kappa_dil = float(dilatancy_strain)
        # the default (β = η for every κ) takes the original, associated code path bit for bit
        self.associated = dilatancy is None and np.isinf(self.kappa_dil)
        self.params = dict(
            youngs_modulus=E,
            poisson_ratio=nu,
            friction=self.friction,
            initial_hardening=self.k0,
            saturated_hardening=self.k_inf,
            hardening_strain=self.kappa_ref,
            kinematic_modulus=self.kinematic,
            softening=self.k_soft,
            softening_strain=self.kappa_soft,
            dilatancy=None if dilatancy is None else self.dilatancy0,
            dilatancy_strain=self.kappa_dil,
        )
        # h = 3G + H_k + K η β + k'(κ) > 0 for every κ ≥ 0 (β ↓ 0 for a finite κd)
        h_min = (
            3 * self.shear
            + self.kinematic
            + (self.bulk * self.friction * self.dilatancy0 if np.isinf(self.kappa_dil) else 0.0)
            + self.min_hardening_slope()
        )
        if not h_min > 0:
            raise ValueError(
                f"elastoplastic.softening: invalid value {self.k_soft!r}: the softening slope "
                f"k_s/κs = {self.k_soft / self.kappa_soft:.4g} Pa makes the plastic modulus "
                f"3G + H_k + min Kηβ + min k'(κ) = {h_min:.4g} Pa ≤ 0 (see the config schema)"
            )
        self.elastic_tangent = self.bulk * np.outer(_ONE, _ONE) + 2 * self.shear * _I_DEV

        sigma0 = initial_stress_array(initial_stress, self.n_points)
        s0, p0 = _split(sigma0)
        bad = np.flatnonzero(_SQRT32 * _norm(s0) - self.friction * p0 - self.k0 > 1e-9 * (np.abs(p0) + 1.0))
        if bad.size:
            raise ValueError(f"elastoplastic: initial stress outside the yield surface at points {bad[:10].tolist()}")
        self._state = {
            "strain": np.zeros((self.n_points, 6)),
            "stress": sigma0,
            "back_stress": np.zeros((self.n_points, 6)),
            "kappa": np.zeros(self.n_points),
        }
        self._trial = None
        self._last_plastic = np.zeros(self.n_points, dtype=bool)

    @classmethod
    def from_config(cls, n_points: int, config: dict, initial_stress="consolidated") -> "Elastoplastic":
        """Parameters from ``config['elastoplastic']``; the initial stress defaults to the
        consolidated state −p0·1 with p0 = ``specimen.confining_pressure``."""
        if isinstance(initial_stress, str) and initial_stress == "consolidated":
            p0 = config["specimen"]["confining_pressure"]
            initial_stress = -p0 * _ONE
        params = {k: config["elastoplastic"].get(k, v) for k, v in DEFAULTS.items()}
        return cls(n_points, **params, initial_stress=initial_stress)

    # -- hardening ---------------------------------------------------------------------
    def hardening(self, kappa: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """k(κ) and dk/dκ."""
        decay = np.exp(-kappa / self.kappa_ref)
        k, dk = self.k0 + (self.k_inf - self.k0) * (1 - decay), (self.k_inf - self.k0) / self.kappa_ref * decay
        if self.k_soft:
            soft = np.exp(-kappa / self.kappa_soft)
            k, dk = k - self.k_soft * (1 - soft), dk - self.k_soft / self.kappa_soft * soft
        return k, dk

    def min_hardening_slope(self) -> float:
        """min over κ ≥ 0 of dk/dκ = a exp(−κ/κr) − c exp(−κ/κs) (a, c ≥ 0): at κ = 0, at the
        stationary point of dk/dκ, or its limit 0 at κ → ∞."""
        a, c = (self.k_inf - self.k0) / self.kappa_ref, self.k_soft / self.kappa_soft
        candidates = [0.0, a - c]
        if a > 0 and c > 0 and self.kappa_ref != self.kappa_soft:
            kappa = np.log(c * self.kappa_ref / (a * self.kappa_soft)) / (1 / self.kappa_soft - 1 / self.kappa_ref)
            if kappa > 0:
                candidates.append(float(self.hardening(np.array([kappa]))[1][0]))
        return min(candidates)

    def dilatancy(self, kappa: np.ndarray) -> np.ndarray:
        """β(κ) = β0 exp(−κ/κd): plastic volumetric strain (tension positive) per unit Δλ."""
        return self.dilatancy0 * np.exp(-np.asarray(kappa, dtype=float) / self.kappa_dil)

    def yield_function(self, stress: np.ndarray, back_stress: np.ndarray, kappa: np.ndarray) -> np.ndarray:
        s, p = _split(np.asarray(stress, dtype=float).reshape(-1, 6))
        return _SQRT32 * _norm(s - back_stress) - self.friction * p - self.hardening(kappa)[0]

    # -- the interface -----------------------------------------------------------------
    def evaluate(self, strain, need_tangent: bool = True):
        strain = self._check_strain(strain)
        st = self._state
        K, G, eta, Hk = self.bulk, self.shear, self.friction, self.kinematic
        d_strain = strain - st["strain"]
        d_vol = d_strain[:, :3].sum(axis=1)
        stress_trial = st["stress"] + K * d_vol[:, None] * _ONE + 2 * G * (d_strain - d_vol[:, None] / 3 * _ONE)
        s_tr, p_tr = _split(stress_trial)
        xi_tr = s_tr - st["back_stress"]
        xi_norm = _norm(xi_tr)
        f_trial = _SQRT32 * xi_norm - eta * p_tr - self.hardening(st["kappa"])[0]
        scale = np.abs(p_tr) + self.k_inf + 1.0  # Pa: tolerance scale of the yield check
        plastic = f_trial > 1e-12 * scale

        stress = stress_trial.copy()
        back = st["back_stress"].copy()
        kappa = st["kappa"].copy()
        tangent = np.broadcast_to(self.elastic_tangent, (self.n_points, 6, 6)).copy() if need_tangent else None

        if plastic.any():
            idx = np.flatnonzero(plastic)
            q_tr, p_t, kap_n = _SQRT32 * xi_norm[idx], p_tr[idx], st["kappa"][idx]
            # β explicit within the step (at the converged κ_n): a constant of the return
            beta = eta if self.associated else self.dilatancy(kap_n)
            linear = 3 * G + Hk + (K * eta**2 if self.associated else K * eta * beta)
            dlam = np.zeros(idx.size)
            lower, upper = np.zeros(idx.size), np.full(idx.size, np.inf)  # bracket: r(lower) > 0 > r(upper)
            for _ in range(60):
                k, dk = self.hardening(kap_n + dlam)
                r = q_tr - eta * p_t - k - linear * dlam
                if np.all(np.abs(r) <= 1e-12 * scale[idx]):
                    break
                newton = dlam + r / (linear + dk)
                if self.k_soft:
                    # r is strictly decreasing, but softening can make it concave: a Newton step
                    # off the bracket of the root bisects instead (without softening r is convex
                    # and Newton from Δλ = 0 converges monotonically on its own)
                    lower = np.where(r > 0, dlam, lower)
                    upper = np.where(r < 0, dlam, upper)
                    newton = np.where((newton < lower) | (newton > upper), 0.5 * (lower + upper), newton)
                dlam = newton
            else:
                worst = idx[np.argmax(np.abs(r))]
                raise MaterialPointError(f"elastoplastic: return mapping did not converge at Gauss point {worst}")
            q_xi = q_tr - (3 * G + Hk) * dlam
            apex = q_xi <= 0
            if apex.any():
                raise MaterialPointError(
                    "elastoplastic: trial stress beyond the cone apex (tension) at Gauss points "
                    f"{idx[apex][:10].tolist()}"
                )
            n_hat = xi_tr[idx] / xi_norm[idx, None]
            p_new = p_t + K * beta * dlam
            s_new = s_tr[idx] - _SQRT6 * G * dlam[:, None] * n_hat
            stress[idx] = s_new - p_new[:, None] * _ONE
            back[idx] += _SQRT23 * Hk * dlam[:, None] * n_hat
            kappa[idx] = kap_n + dlam
            if need_tangent:
                b = _SQRT6 * G * dlam / xi_norm[idx]
                _, dk = self.hardening(kappa[idx])
                h = linear + dk
                v_f = _SQRT6 * G * n_hat + K * eta * _ONE  # yield side: dΔλ = v_f · dε / h
                v_g = v_f if self.associated else _SQRT6 * G * n_hat + (K * beta)[:, None] * _ONE  # flow side
                tangent[idx] = (
                    K * np.outer(_ONE, _ONE)
                    + 2 * G * (1 - b)[:, None, None] * _I_DEV
                    + 2 * G * b[:, None, None] * n_hat[:, :, None] * n_hat[:, None, :]
                    - v_g[:, :, None] * v_f[:, None, :] / h[:, None, None]
                )
        self._check_response(stress, tangent, "elastoplastic")
        self._trial = {"strain": strain.copy(), "stress": stress, "back_stress": back, "kappa": kappa}
        self._last_plastic = plastic
        return stress.copy(), tangent

    def commit(self, strain=None) -> None:
        self._trial_at(strain, None if self._trial is None else self._trial["strain"])
        if self._trial is None:
            raise RuntimeError("elastoplastic: commit() before any evaluate()")
        self._state = self._trial
        self._trial = None
        self._committed_plastic = self._last_plastic.copy()

    def step_info(self) -> dict[str, float]:
        plastic = getattr(self, "_committed_plastic", np.zeros(self.n_points, dtype=bool))
        return {"plastic_fraction": float(plastic.mean()), "mean_kappa": float(self._state["kappa"].mean())}

    def get_state(self) -> dict[str, Any]:
        state = {k: v.copy() for k, v in self._state.items()}
        state["plastic"] = getattr(self, "_committed_plastic", np.zeros(self.n_points, dtype=bool)).copy()
        return state

    def set_state(self, state: dict[str, Any]) -> None:
        self._state = {k: np.array(state[k], dtype=float) for k in ("strain", "stress", "back_stress", "kappa")}
        self._committed_plastic = np.array(state.get("plastic", np.zeros(self.n_points)), dtype=bool)
        self._trial = None
