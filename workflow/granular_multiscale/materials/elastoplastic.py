"""Analytic elastoplastic reference model: Drucker–Prager cone with combined hardening.

A reference whose truth is known (exact, fast, with a consistent tangent) for testing the
solver and the surrogate without YADE. Tension positive stress; p = −tr σ / 3 is the
(compression positive) mean pressure; s = dev σ; ‖·‖ is the tensor norm, and
Q(x) = sqrt(3/2)‖x‖ the von Mises-type magnitude of a deviatoric tensor.

Elasticity (bulk K, shear G from E, ν):      σ = σ_n + K tr(Δε) 1 + 2G dev(Δε) − plastic part

Yield surface (cone around the back-stress α, deviatoric):

    f(σ, α, κ) = Q(s − α) − η p − k(κ) ≤ 0
    k(κ) = k0 + (k∞ − k0)(1 − exp(−κ/κr))          isotropic hardening (saturating)

Associated flow and hardening (Δλ ≥ 0, n̂ = (s − α)/‖s − α‖):

    Δεᵖ = Δλ (sqrt(3/2) n̂ + η/3 1)      deviatoric part + dilatancy η Δλ (tension positive)
    Δα  = (2/3) H_k dev(Δεᵖ) = sqrt(2/3) H_k Δλ n̂  linear kinematic (Prager) hardening
    Δκ  = Δλ = sqrt(2/3) ‖dev Δεᵖ‖                equivalent deviatoric plastic strain

Because α only moves the cone, a reversal of loading yields again on the opposite side of
the cone (reverse yielding): unloading–reloading makes a closed hysteresis loop. The
friction η is a constant and the isotropic hardening enters as k(κ) (not through η): this
keeps the consistent tangent exactly symmetric, so the 21 stored entries hold all of it.

Return mapping (backward Euler, radial: n̂ = direction of the trial ξ_tr = s_tr − α_n)
reduces to one scalar equation per point, solved by a vectorised Newton iteration over all
plastic points at once (it converges monotonically: r is convex and decreasing for k∞ ≥ k0):

    r(Δλ) = Q(ξ_tr) − η p_tr − k(κ_n + Δλ) − (3G + H_k + K η²) Δλ = 0

    s = s_tr − sqrt(6) G Δλ n̂,   p = p_tr + K η Δλ,   α = α_n + sqrt(2/3) H_k Δλ n̂

Consistent tangent (Voigt, acting on the engineering strain), with β = sqrt(6) G Δλ/‖ξ_tr‖,
v = sqrt(6) G n̂ + K η 1 and h = 3G + H_k + K η² + k'(κ):

    D = K 1⊗1 + 2G(1 − β) I_dev + 2G β n̂⊗n̂ − v⊗v / h

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
        initial_stress=None,
    ):
        super().__init__(n_points)
        checks = {
            "youngs_modulus": youngs_modulus > 0,
            "poisson_ratio": 0 <= poisson_ratio < 0.5,
            "friction": friction >= 0,
            "initial_hardening": initial_hardening >= 0,
            "saturated_hardening": saturated_hardening >= initial_hardening,
            "hardening_strain": hardening_strain > 0,
            "kinematic_modulus": kinematic_modulus >= 0,
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
        self.params = dict(
            youngs_modulus=E,
            poisson_ratio=nu,
            friction=self.friction,
            initial_hardening=self.k0,
            saturated_hardening=self.k_inf,
            hardening_strain=self.kappa_ref,
            kinematic_modulus=self.kinematic,
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
        return self.k0 + (self.k_inf - self.k0) * (1 - decay), (self.k_inf - self.k0) / self.kappa_ref * decay

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
            linear = 3 * G + Hk + K * eta**2
            dlam = np.zeros(idx.size)
            for _ in range(50):
                k, dk = self.hardening(kap_n + dlam)
                r = q_tr - eta * p_t - k - linear * dlam
                if np.all(np.abs(r) <= 1e-12 * scale[idx]):
                    break
                dlam = dlam + r / (linear + dk)
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
            p_new = p_t + K * eta * dlam
            s_new = s_tr[idx] - _SQRT6 * G * dlam[:, None] * n_hat
            stress[idx] = s_new - p_new[:, None] * _ONE
            back[idx] += _SQRT23 * Hk * dlam[:, None] * n_hat
            kappa[idx] = kap_n + dlam
            if need_tangent:
                beta = _SQRT6 * G * dlam / xi_norm[idx]
                _, dk = self.hardening(kappa[idx])
                h = linear + dk
                v = _SQRT6 * G * n_hat + K * eta * _ONE
                tangent[idx] = (
                    K * np.outer(_ONE, _ONE)
                    + 2 * G * (1 - beta)[:, None, None] * _I_DEV
                    + 2 * G * beta[:, None, None] * n_hat[:, :, None] * n_hat[:, None, :]
                    - v[:, :, None] * v[:, None, :] / h[:, None, None]
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
