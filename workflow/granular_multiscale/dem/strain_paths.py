"""Designed strain histories for RVEs driven without FEM (rule ``rve_paths``), as data.

A set of trajectories is ``strain[trajectory, step, 6]`` for steps 0..n_steps (Voigt order
11, 22, 33, 23, 13, 12, tensorial shear, tension positive; step 0 = 0, the consolidated
state), each with a ``family`` label, generated from the config section ``rve_paths`` and
seeded by ``seed + sets.<name>.seed_offset`` (every family draws from its own stream, so the
count of one family does not change the trajectories of the others). Families:

axisymmetric
    ε33 = s(t), ε11 = ε22 = −ν·s(t), no shear; ν (``nu_min..nu_max``) is drawn per
    trajectory, ν < 0.5 compacts under compression and ν > 0.5 dilates. The first
    ``1 − extension_fraction`` of the family's trajectories are compressions (s < 0), the rest
    extensions. |s| moves by exactly ``increment`` per step: loading to a first peak, then
    1..3 unload–reload cycles (``cycles_min..cycles_max``) whose peaks (where) and unload
    depths (how far) are drawn, and a last reloading to the final, largest amplitude.
random_walk
    A correlated random walk in the 6-D strain space: the direction of each increment is
    ``correlation`` × the previous one plus noise, reversed with ``reversal_probability`` per
    step, scaled so that its largest component is ``increment``; an increment that would leave
    the bounds is reflected at them (on a trace, eigenvalue or shear bound), or sent back
    towards the origin when the reflection does not fit either.
triaxial
    A drained triaxial test on the RVE alone, as the Gauss points of a specimen see it: ε33 = s(t)
    follows a compression with unload–reload cycles like the axisymmetric family (so it is data
    here), while the lateral and shear strains are *stress controlled* by the driver
    (:func:`lateral_servo`): each increment chooses them from the last converged stress and
    tangent so that σ11 = σ22 = −f·p0 and the shear stresses vanish, f drawn per trajectory
    (``lateral_stress_min_fraction..max``). One DEM evaluation per increment, no iteration: the
    contact tangent is stiffer than the RVE, so the lateral stress lags and the next
    increment corrects it (default scale, 32 trajectories × 80 steps of 400-sphere RVEs: median
    3.3 %, largest 14.5 % off its target; shear stresses below 2.1 kPa). The strain the file records is the strain the RVE got.
plane_strain
    A plane-strain biaxial test on the RVE that goes on into a shear band, as the Gauss points of
    the plane-strain problems see it (x–z plane, y out of plane: ε22 = ε12 = ε23 = 0 throughout).
    Phase 1 (a drawn ``compression_*_fraction`` of the steps): compression along an in-plane
    loading axis n at a drawn angle from z (``max_axis_angle``), by ``increment`` per step with
    unload–reload cycles like the triaxial family's, while the stresses across it are stress
    controlled, t·σ·t = −f·p0 and n·σ·t = 0. Phase 2: simple shear in the frame of a band whose
    direction b makes a drawn angle α with n (``band_angle_*``) and whose normal is m: m·ε·b grows in
    the sense of phase 1's shear to a drawn total (``band_shear_*``), b·ε·b is held (a band does not
    stretch along itself) and m·σ·m goes from its value at the switch to a drawn share of it
    (``normal_stress_*_ratio``, over the first ``normal_stress_ramp_fraction`` of the phase: the
    material beside a band unloads as the specimen softens), so the RVE dilates or compacts as it
    wants. The share 1 − ``band_probability`` of the trajectories go on with phase 1's control
    instead, compressing along n by the same total in phase 2: the points of a band that a coarse
    mesh resolves by whole elements stretch along the band too, as in a long biaxial test. The
    designed strain is the imposed part (−s·n⊗n, then the band shear); the driver chooses the other
    components (:func:`mixed_control`, rows of :func:`plane_strain_rows`).
isotropic_triaxial
    A drained triaxial test at another confining pressure, from the consolidated state at p0: phase
    0 (``isotropic_steps``) takes the three normal stresses linearly from −p0 to −g·p0 with the
    shear stresses at zero (all six components stress controlled); phase 1 compresses ε33 by
    ``increment`` per step with unload–reload cycles like the triaxial family while σ11 = σ22 =
    −g·p0 and the shear stresses vanish. g is drawn per trajectory, log-uniformly in
    ``pressure_min_fraction..max`` (a specimen at 0.3–4 times the pressure the RVEs were
    consolidated at). The designed strain is the imposed part, zero in phase 0 and then ε33 =
    −increment·level (the driver adds each increment to the strain the RVE got, so phase 1 starts
    from the compacted state); the other components come from :func:`mixed_control` with the rows
    of :func:`isotropic_triaxial_rows`.
proportional
    ε(t) = α(t)·n for a random unit direction n of the 6-D strain space: α grows monotonically
    to a drawn amplitude (``min_amplitude_fraction``..1 of the largest the bounds allow along
    n) and, with ``return_probability``, comes back part way (up to ``max_return_fraction`` of
    it). The increments are as large as the amplitude needs in n_steps, at most ``increment``
    (an amplitude that n_steps such increments do not reach is cut to what they reach).

Bounds (every generated history is checked against them): principal strains
|ε_i| ≤ ``max_strain``, shear components |ε_ij| ≤ ``max_shear``, volumetric extension
tr ε ≤ ``max_volumetric_extension`` (so an RVE keeps its contact network) and compaction
−tr ε ≤ ``max_volumetric_compaction`` (so the stresses stay in the range a specimen sees).

``python -m granular_multiscale.dem.strain_paths [--config FILE] [SET ...]`` prints what a
set costs in DEM evaluations and particle-steps, without running YADE.
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import dataclass

import numpy as np

from ..config import ConfigError, load_config, merged, rve_paths_section
from ..tensors import ENGINEERING_FACTOR, tensor_to_voigt, voigt_to_tensor
from .worker import steps_for_increment

FAMILIES = ("axisymmetric", "random_walk", "proportional", "triaxial", "plane_strain", "isotropic_triaxial")
#: families whose lateral strains the driver sets from the RVE's response (mixed control)
STRESS_CONTROLLED = ("triaxial", "plane_strain", "isotropic_triaxial")
#: the plane of the plane-strain problems and family: x (axis 0) and z (axis 2); y is out of plane
IN_PLANE_X, OUT_OF_PLANE, IN_PLANE_Z = np.eye(3)
#: absolute slack (strain) of the bound checks: round-off of eigenvalues and sums
BOUND_SLACK = 1e-12
MAX_TRIES = 500


@dataclass(frozen=True)
class StrainBounds:
    max_strain: float
    max_shear: float
    max_volumetric_extension: float
    max_volumetric_compaction: float

    def violation(self, strain: np.ndarray) -> np.ndarray:
        """[..., 6] -> [...]: by how much a strain exceeds its tightest bound (<= 0: within all)."""
        strain = np.asarray(strain, dtype=float)
        principal = np.abs(np.linalg.eigvalsh(voigt_to_tensor(strain))).max(axis=-1) - self.max_strain
        shear = np.abs(strain[..., 3:]).max(axis=-1) - self.max_shear
        trace = strain[..., :3].sum(axis=-1)
        volumetric = np.maximum(trace - self.max_volumetric_extension, -trace - self.max_volumetric_compaction)
        return np.maximum(np.maximum(principal, shear), volumetric)

    def largest_along(self, direction: np.ndarray) -> float:
        """Largest t >= 0 with t·direction within the bounds."""
        n = np.asarray(direction, dtype=float)
        limits = [self.max_strain / np.abs(np.linalg.eigvalsh(voigt_to_tensor(n))).max()]
        if np.abs(n[3:]).max() > 0:
            limits.append(self.max_shear / np.abs(n[3:]).max())
        if n[:3].sum() > 0:
            limits.append(self.max_volumetric_extension / n[:3].sum())
        if n[:3].sum() < 0:
            limits.append(self.max_volumetric_compaction / -n[:3].sum())
        return float(min(limits))


@dataclass(frozen=True)
class StrainPaths:
    """A generated set: strain [trajectory, step, 6], family [trajectory] and, per trajectory,
    what was drawn for it (``parameters``: ν, sense and reversal steps; direction, amplitude ...)."""

    name: str
    strain: np.ndarray
    family: np.ndarray
    parameters: tuple[dict, ...]
    increment: float
    bounds: StrainBounds

    @property
    def n_trajectories(self) -> int:
        return self.strain.shape[0]

    @property
    def n_steps(self) -> int:
        return self.strain.shape[1] - 1

    def largest_increment(self) -> float:
        return float(np.abs(np.diff(self.strain, axis=1)).max())


# ------------------------------------------------------------------------------ config
def set_definition(config: dict, name: str) -> dict:
    """The set ``rve_paths.sets.<name>`` (counts per family, n_steps, seed_offset), checked."""
    sets = config["rve_paths"]["sets"]
    if name not in sets:
        raise ConfigError(f"config key 'rve_paths.sets': no set named {name!r} (defined: {sorted(sets)})")
    definition = sets[name]
    if sum(definition[f] for f in FAMILIES) < 1:
        raise ConfigError(f"config key 'rve_paths.sets.{name}': no trajectories (give a positive count to one of "
                          f"{', '.join(FAMILIES)})")
    return definition


def check_section(section: dict) -> None:
    """What the schema cannot say: ranges given by pairs of keys, and an increment that fits the bounds."""
    for family, low, high in (("axisymmetric", "nu_min", "nu_max"), ("axisymmetric", "cycles_min", "cycles_max"),
                              ("triaxial", "cycles_min", "cycles_max"),
                              ("triaxial", "lateral_stress_min_fraction", "lateral_stress_max_fraction"),
                              ("plane_strain", "cycles_min", "cycles_max"),
                              ("plane_strain", "lateral_stress_min_fraction", "lateral_stress_max_fraction"),
                              ("plane_strain", "compression_min_fraction", "compression_max_fraction"),
                              ("plane_strain", "band_angle_min", "band_angle_max"),
                              ("plane_strain", "band_shear_min", "band_shear_max"),
                              ("plane_strain", "normal_stress_min_ratio", "normal_stress_max_ratio"),
                              ("isotropic_triaxial", "cycles_min", "cycles_max"),
                              ("isotropic_triaxial", "pressure_min_fraction", "pressure_max_fraction")):
        if section[family][low] > section[family][high]:
            raise ConfigError(f"config key 'rve_paths.{family}.{low}': {section[family][low]} is larger than "
                              f"rve_paths.{family}.{high} = {section[family][high]}")
    increment = section["increment"]
    # any increment of size `increment` from the origin stays inside (the random walk's last resort)
    for key, room in (("max_strain", 3 * increment), ("max_volumetric_extension", 3 * increment),
                      ("max_volumetric_compaction", 3 * increment), ("max_shear", increment)):
        if section[key] < room:
            raise ConfigError(f"config key 'rve_paths.increment': {increment} does not fit rve_paths.{key} = "
                              f"{section[key]} (needs at least {room:g})")


def set_section(config: dict, name: str | None = None) -> dict:
    """The ``rve_paths`` settings (bounds, increment, family settings, contact loss; not ``sets``)
    that set `name` is drawn and driven with: the section's, with what the set's own ``settings``
    replace (e.g. a set of long triaxial trajectories to larger strains: ``{max_strain: 0.09}``).
    Without a name, the section's."""
    section = rve_paths_section(config)
    if name is None:
        return section
    return merged(section, set_definition(config, name).get("settings", {}))


def bounds_from_config(config: dict, name: str | None = None) -> StrainBounds:
    s = set_section(config, name)
    return StrainBounds(s["max_strain"], s["max_shear"], s["max_volumetric_extension"], s["max_volumetric_compaction"])


def strain_paths_from_config(config: dict, name: str) -> StrainPaths:
    """Generate the set ``rve_paths.sets.<name>`` of a validated config."""
    section = set_section(config, name)
    definition = set_definition(config, name)
    check_section(section)
    return generate(
        name, {f: definition[f] for f in FAMILIES}, definition["n_steps"],
        int(config["seed"]) + definition["seed_offset"], section["increment"], bounds_from_config(config, name),
        {f: section[f] for f in FAMILIES},
    )


# ------------------------------------------------------------------------------ generation
def generate(name: str, counts: dict[str, int], n_steps: int, seed: int, increment: float, bounds: StrainBounds,
             family_settings: dict[str, dict]) -> StrainPaths:
    """The trajectories of every family, in the order of :data:`FAMILIES`; checks the bounds."""
    draw = {"axisymmetric": _axisymmetric, "random_walk": _random_walk, "proportional": _proportional,
            "triaxial": _triaxial, "plane_strain": _plane_strain, "isotropic_triaxial": _isotropic_triaxial}
    strains, families, parameters = [], [], []
    for index, family in enumerate(FAMILIES):
        rng = np.random.default_rng([seed, index])
        count = counts.get(family, 0)
        for k in range(count):
            strain, info = draw[family](rng, k, count, n_steps, increment, bounds, family_settings[family], name)
            strains.append(strain)
            families.append(family)
            parameters.append(info)
    strain = np.stack(strains)
    # a stress-controlled trajectory's volume is the RVE's response, not data: only its designed
    # axial strain is checked (against the principal-strain bound); a plane-strain trajectory's band
    # shear has its own bound (band_shear_max), its compression the principal-strain bound by construction
    axial_only = StrainBounds(bounds.max_strain, bounds.max_shear, np.inf, np.inf)
    family = np.array(families)
    worst = np.where(np.isin(family, STRESS_CONTROLLED)[:, None], axial_only.violation(strain),
                     bounds.violation(strain))
    worst[family == "plane_strain"] = 0.0
    if worst.max() > BOUND_SLACK or np.any(strain[:, 0] != 0.0):
        t, step = np.unravel_index(np.argmax(worst), worst.shape)
        raise AssertionError(f"RVE-path set {name!r}: trajectory {t} ({families[t]}) leaves its bounds at step {step} "
                             f"by {worst.max():.3g} (a bug of strain_paths)")
    return StrainPaths(name, strain, np.array(families), tuple(parameters), increment, bounds)


def _axisymmetric(rng, k, count, n_steps, increment, bounds, settings, name):
    extension = k >= count - round(settings["extension_fraction"] * count)
    sense = 1.0 if extension else -1.0
    nu = float(rng.uniform(settings["nu_min"], settings["nu_max"]))
    # largest |ε33|: principal strains |ε33| and |ν ε33|; tr ε = ε33 (1 − 2ν) within the volumetric bounds
    largest = bounds.max_strain / max(1.0, abs(nu))
    dilation = sense * (1.0 - 2.0 * nu)
    if dilation > 0:
        largest = min(largest, bounds.max_volumetric_extension / dilation)
    if dilation < 0:
        largest = min(largest, bounds.max_volumetric_compaction / -dilation)
    cap = int(math.floor(largest / increment + 1e-9))  # in increments
    level, reversals = _cycle_levels(rng, n_steps, cap, increment, settings, name, "axisymmetric",
                                     f"|eps33| <= {cap * increment:g}, the rve_paths bounds at nu = {nu:.3f}",
                                     "n_steps, rve_paths.axisymmetric.cycles_min/cycles_max or the bounds")
    e33 = sense * increment * level
    strain = np.zeros((n_steps + 1, 6))
    strain[:, 2] = e33
    strain[:, 0] = strain[:, 1] = -nu * e33
    return strain, {"nu": nu, "sense": "extension" if extension else "compression", "reversal_steps": reversals,
                    "largest_level": int(level.max())}


def _triaxial(rng, k, count, n_steps, increment, bounds, settings, name):
    """The axial part of a stress-controlled triaxial trajectory (lateral strains: the driver)."""
    cap = int(math.floor(bounds.max_strain / increment + 1e-9))
    level, reversals = _cycle_levels(rng, n_steps, cap, increment, settings, name, "triaxial",
                                     f"|eps33| <= {cap * increment:g}",
                                     "n_steps, rve_paths.triaxial.cycles_min/cycles_max or max_strain")
    strain = np.zeros((n_steps + 1, 6))
    strain[:, 2] = -increment * level
    fraction = float(rng.uniform(settings["lateral_stress_min_fraction"], settings["lateral_stress_max_fraction"]))
    return strain, {"sense": "compression", "reversal_steps": reversals, "largest_level": int(level.max()),
                    "lateral_stress_fraction": fraction}


def _isotropic_triaxial(rng, k, count, n_steps, increment, bounds, settings, name):
    """The imposed part of a triaxial trajectory at another pressure: zero while the isotropic phase
    changes the pressure (stress controlled), then ε33 with cycles (lateral strains: the driver)."""
    n_isotropic = settings["isotropic_steps"]
    cap = int(math.floor(bounds.max_strain / increment + 1e-9))
    level, reversals = _cycle_levels(rng, n_steps - n_isotropic, cap, increment, settings, name, "isotropic_triaxial",
                                     f"|eps33| <= {cap * increment:g}, after {n_isotropic} isotropic steps",
                                     "n_steps, rve_paths.isotropic_triaxial.isotropic_steps, cycles_min/cycles_max "
                                     "or max_strain")
    strain = np.zeros((n_steps + 1, 6))
    strain[n_isotropic:, 2] = -increment * level
    fraction = float(np.exp(rng.uniform(math.log(settings["pressure_min_fraction"]),
                                        math.log(settings["pressure_max_fraction"]))))
    return strain, {"sense": "compression", "pressure_fraction": fraction, "isotropic_steps": n_isotropic,
                    "reversal_steps": [n_isotropic + r for r in reversals], "largest_level": int(level.max())}


def _plane_strain(rng, k, count, n_steps, increment, bounds, settings, name):
    """The imposed part of a plane-strain trajectory: −s·n⊗n with cycles, then the band shear (or,
    in the share 1 − ``band_probability``, the compression along n goes on as far)."""
    n_compression = int(round(rng.uniform(settings["compression_min_fraction"],
                                          settings["compression_max_fraction"]) * n_steps))
    n_compression = min(max(n_compression, 1), n_steps - 1)
    cap = int(math.floor(bounds.max_strain / increment + 1e-9))
    level, reversals = _cycle_levels(rng, n_compression, cap, increment, settings, name, "plane-strain compression",
                                     f"|eps_nn| <= {cap * increment:g}",
                                     "n_steps, rve_paths.plane_strain.compression_min_fraction or cycles_min/cycles_max")
    axis_angle = float(rng.uniform(-settings["max_axis_angle"], settings["max_axis_angle"]))
    band_angle = float(rng.uniform(settings["band_angle_min"], settings["band_angle_max"]) * rng.choice([-1.0, 1.0]))
    fraction = float(rng.uniform(settings["lateral_stress_min_fraction"], settings["lateral_stress_max_fraction"]))
    band_shear = float(rng.uniform(settings["band_shear_min"], settings["band_shear_max"]))
    normal_ratio = float(rng.uniform(settings["normal_stress_min_ratio"], settings["normal_stress_max_ratio"]))
    band = bool(rng.random() < settings["band_probability"])
    n, t, m, b = plane_strain_frame(axis_angle, band_angle)
    strain = np.zeros((n_steps + 1, 6))
    strain[:n_compression + 1] = -increment * level[:, None] * _dyad(n, n)[None, :]
    progress = np.arange(1, n_steps - n_compression + 1) / (n_steps - n_compression)
    if band:  # m·ε·b grows in the sense phase 1 sheared it (m·(−s n⊗n)·b = s·sin α·cos α)
        second = np.sign(band_angle) * band_shear * progress[:, None] * (_dyad(m, b) + _dyad(b, m))[None, :]
    else:  # the biaxial compression goes on, by band_shear along n
        second = -band_shear * progress[:, None] * _dyad(n, n)[None, :]
    strain[n_compression + 1:] = strain[n_compression] + second
    return strain, {"sense": "compression", "reversal_steps": reversals, "largest_level": int(level.max()),
                    "lateral_stress_fraction": fraction, "axis_angle": axis_angle, "band_angle": band_angle,
                    "second_phase": "band" if band else "biaxial",
                    "band_shear": band_shear, "normal_stress_ratio": normal_ratio,
                    "normal_stress_ramp_steps": max(1, round(settings["normal_stress_ramp_fraction"]
                                                             * (n_steps - n_compression))),
                    "compression_steps": n_compression}


def plane_strain_frame(axis_angle: float, band_angle: float) -> tuple[np.ndarray, ...]:
    """Unit vectors (n, t, m, b) in the x–z plane: the loading axis n at ``axis_angle`` degrees from z
    (towards x), t across it, the band direction b at ``band_angle`` degrees from n (towards t) and
    the band normal m."""
    theta, alpha = np.radians(axis_angle), np.radians(band_angle)
    n = np.sin(theta) * IN_PLANE_X + np.cos(theta) * IN_PLANE_Z
    t = np.cos(theta) * IN_PLANE_X - np.sin(theta) * IN_PLANE_Z
    b = np.cos(alpha) * n + np.sin(alpha) * t
    m = -np.sin(alpha) * n + np.cos(alpha) * t
    return n, t, m, b


def _dyad(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a⊗b in Voigt order (11, 22, 33, 23, 13, 12) with its symmetric part's tensorial shear."""
    return tensor_to_voigt(0.5 * (np.outer(a, b) + np.outer(b, a)))


def contraction(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Weights w [6] with w·v = a·T·b for the symmetric tensor T of a Voigt vector v (tensorial
    shear for strain, σ23 ... for stress: the off-diagonal entries count twice)."""
    return _dyad(a, b) * ENGINEERING_FACTOR


def plane_strain_rows(parameters: dict, step: int, pressure: float,
                      stress_at_switch: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The six conditions a plane-strain trajectory's increment step−1 → step satisfies, as rows of
    :func:`mixed_control`: weights [6, 6], which rows are stress rows [6], and their stress targets
    [6] (a strain row takes its increment from the designed strain). ``pressure``: p0;
    ``stress_at_switch``: the converged stress at the last compression step; the band phase takes its
    m·σ·m to ``normal_stress_ratio`` times that value over its first ``normal_stress_ramp_steps``
    (linearly) and holds it there (the material beside a band unloads as the specimen softens)."""
    n, t, m, b = plane_strain_frame(parameters["axis_angle"], parameters["band_angle"])
    rows = [contraction(OUT_OF_PLANE, OUT_OF_PLANE), contraction(IN_PLANE_X, OUT_OF_PLANE),
            contraction(OUT_OF_PLANE, IN_PLANE_Z)]  # plane strain: ε22 = ε12 = ε23 = 0
    targets = np.zeros(6)
    if step <= parameters["compression_steps"] or parameters["second_phase"] == "biaxial":
        # ε_nn imposed; σ_tt = −f·p0, σ_nt = 0
        rows += [contraction(n, n), contraction(t, t), contraction(n, t)]
        stress_rows = np.array([False, False, False, False, True, True])
        targets[4] = -parameters["lateral_stress_fraction"] * pressure
    else:  # ε_bb held, ε_mb imposed; σ_mm from its value at the switch to a drawn share of it
        rows += [contraction(b, b), contraction(m, b), contraction(m, m)]
        stress_rows = np.array([False, False, False, False, False, True])
        ramp = min(1.0, (step - parameters["compression_steps"]) / parameters["normal_stress_ramp_steps"])
        targets[5] = (1.0 + (parameters["normal_stress_ratio"] - 1.0) * ramp) * (contraction(m, m) @ stress_at_switch)
    return np.array(rows), stress_rows, targets


def isotropic_triaxial_rows(parameters: dict, step: int, pressure: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The six conditions an isotropic-triaxial trajectory's increment step−1 → step satisfies, as
    rows of :func:`mixed_control` (weights [6, 6]: the Voigt components themselves; which rows are
    stress rows [6]; their stress targets [6]). ``pressure``: p0. Phase 0 (steps 1..isotropic_steps):
    every component stress controlled, the normal stresses at step/isotropic_steps of the way from
    −p0 to −g·p0, the shear stresses 0. Phase 1: ε33 imposed (the designed increment), σ11 = σ22 =
    −g·p0, shear stresses 0."""
    g, n_isotropic = parameters["pressure_fraction"], parameters["isotropic_steps"]
    targets = np.zeros(6)
    if step <= n_isotropic:
        stress_rows = np.ones(6, dtype=bool)
        targets[:3] = -pressure * (1.0 + (g - 1.0) * step / n_isotropic)
    else:
        stress_rows = np.array([True, True, False, True, True, True])
        targets[:2] = -g * pressure
    return np.eye(6), stress_rows, targets


def mixed_control(strain: np.ndarray, stress: np.ndarray, tangent: np.ndarray, designed_increment: np.ndarray,
                  weights: np.ndarray, stress_rows: np.ndarray, stress_targets: np.ndarray,
                  largest: float) -> np.ndarray:
    """Next strain [n, 6] under mixed control: row k of ``weights`` [n, 6, 6] either fixes w_k·Δε to
    w_k·``designed_increment`` (a strain row) or, where ``stress_rows`` [n, 6], asks w_k·(σ + D·Δε)
    = ``stress_targets`` with the converged stress and tangent D (on engineering strain). One linear
    solve per point; each increment component is clipped to ±``largest``."""
    d = tangent * ENGINEERING_FACTOR[None, None, :]  # acts on the tensorial strain increment
    matrix = np.where(stress_rows[..., None], weights @ d, weights)
    rhs = np.where(stress_rows, stress_targets - np.einsum("nkj,nj->nk", weights, stress),
                   np.einsum("nkj,nj->nk", weights, designed_increment))
    increment = np.clip(np.linalg.solve(matrix, rhs[..., None])[..., 0], -largest, largest)
    return strain + increment


#: components the servo controls (σ11, σ22 to −f·p0, shear stresses to 0) and the one it imposes (ε33)
_LATERAL, _AXIAL = np.array([0, 1, 3, 4, 5]), 2


def lateral_servo(strain: np.ndarray, stress: np.ndarray, tangent: np.ndarray, axial_increment: np.ndarray,
                  lateral_stress: np.ndarray, largest: float) -> np.ndarray:
    """Next strain [n, 6] of stress-controlled trajectories: ε33 moves by ``axial_increment``; the
    lateral and shear strain increments solve D_ll·Δε_l = (σ_l,target − σ_l) − D_la·Δε33 with the
    converged tangent D (on engineering strain) and stress, targets σ11 = σ22 = ``lateral_stress``
    (negative: compression), shear 0; each increment component is clipped to ±``largest``."""
    target = np.zeros((len(strain), _LATERAL.size))
    target[:, 0] = target[:, 1] = lateral_stress
    d = tangent * ENGINEERING_FACTOR[None, None, :]  # acts on the tensorial strain increment
    rhs = target - stress[:, _LATERAL] - d[:, _LATERAL, _AXIAL] * axial_increment[:, None]
    d_ll = d[:, _LATERAL][:, :, _LATERAL]
    lateral = np.clip(np.linalg.solve(d_ll, rhs[..., None])[..., 0], -largest, largest)
    out = strain.copy()
    out[:, _AXIAL] += axial_increment
    out[:, _LATERAL] += lateral
    return out


def _cycle_levels(rng, n_steps: int, cap: int, increment: float, settings: dict, name: str, what: str,
                  bound: str, change: str) -> tuple[np.ndarray, list[int]]:
    """:func:`_cycles`, or a ConfigError naming the set's n_steps, the bound and what to change."""
    found = _cycles(rng, n_steps, cap, settings) if n_steps > 0 else None
    if found is None:
        raise ConfigError(
            f"config key 'rve_paths.sets.{name}.n_steps': {n_steps} {what} increments of {increment:g} with "
            f"{settings['cycles_min']}..{settings['cycles_max']} unload-reload cycles cannot be laid out (c cycles need "
            f"at least 2c + 2 steps, and enough unloading to end within {bound}); change {change}")
    return found


def _cycles(rng, n_steps: int, cap: int, settings: dict):
    """|ε33| in increments per step 0..n_steps, moving by one per step: up to peak P1, down U1,
    up to P2 > P1, ..., down Uc, up to the final (largest) level F; F + 2ΣU = n_steps.
    Returns (levels, reversal steps) or None when no such path fits under ``cap``."""
    for _ in range(MAX_TRIES):
        c = int(rng.integers(settings["cycles_min"], settings["cycles_max"] + 1))
        if c == 0:  # monotonic
            if n_steps <= cap:
                return np.arange(n_steps + 1, dtype=float), []
            continue
        high = min(cap, n_steps - 2 * c)
        high -= (high - n_steps) % 2  # F has the parity of n_steps
        # F large enough that the unloading (n_steps − F)/2 fits below c peaks under F
        low = max(c + 1, math.ceil(settings["min_amplitude_fraction"] * high),
                  math.ceil((n_steps + 2 * c) / (2 * c + 1)))
        low += (low - n_steps) % 2
        if low > high:
            continue
        final = int(rng.choice(np.arange(low, high + 1, 2)))
        unload_total = (n_steps - final) // 2
        peaks = np.sort(rng.choice(np.arange(1, final), size=c, replace=False))
        if peaks.sum() < unload_total:  # the unloading does not fit below these peaks
            continue
        depths = 1 + _bounded_composition(rng, unload_total - c, peaks - 1)
        levels, reversals = [0], []
        for peak, depth in zip(peaks, depths):
            levels += range(levels[-1] + 1, peak + 1)
            reversals.append(len(levels))
            levels += range(peak - 1, peak - depth - 1, -1)
            reversals.append(len(levels))
        levels += range(levels[-1] + 1, final + 1)
        assert len(levels) == n_steps + 1 and max(levels) == final
        return np.asarray(levels, dtype=float), reversals
    return None


def _bounded_composition(rng, total: int, caps: np.ndarray) -> np.ndarray:
    """Random non-negative integers x_i <= caps_i with Σx = total (Σcaps >= total)."""
    x = np.zeros(len(caps), dtype=int)
    while x.sum() < total:
        room = caps - x
        open_ = np.flatnonzero(room > 0)
        left = total - x.sum()
        share = np.floor(rng.dirichlet(np.ones(len(open_))) * left).astype(int)
        add = np.minimum(share, room[open_])
        if add.sum() == 0:
            add[rng.integers(len(open_))] = 1
        x[open_] += add
    return x


def _random_walk(rng, k, count, n_steps, increment, bounds, settings, name):
    rho = settings["correlation"]
    strain = np.zeros((n_steps + 1, 6))
    direction = rng.standard_normal(6)
    reversals, reflections, returns = [], 0, 0
    for step in range(1, n_steps + 1):
        if step > 1 and rng.random() < settings["reversal_probability"]:
            direction = -direction
            reversals.append(step)
        noise = rng.standard_normal(6) / math.sqrt(6.0)
        direction = rho * direction / np.linalg.norm(direction) + math.sqrt(1.0 - rho**2) * noise
        d = increment * direction / np.abs(direction).max()
        here = strain[step - 1]
        if bounds.violation(here + d) > 0:
            reflections += 1
            d = _reflect(here, d, bounds)
            d = increment * d / np.abs(d).max()
            if bounds.violation(here + d) > 0:  # back towards the origin (inside by convexity)
                returns += 1
                d = -increment * here / np.abs(here).max()
            direction = d
        strain[step] = here + d
    return strain, {"reversal_steps": reversals, "reflections": reflections, "returns_to_origin": returns}


def _reflect(strain: np.ndarray, d: np.ndarray, bounds: StrainBounds) -> np.ndarray:
    """Mirror the outward part of increment ``d`` at each bound that ``strain + d`` crosses."""
    d = d.copy()
    trial = strain + d
    shear = (np.abs(trial[3:]) > bounds.max_shear) & (d[3:] * trial[3:] > 0)
    d[3:][shear] *= -1.0
    values, vectors = np.linalg.eigh(voigt_to_tensor(strain + d))
    for value, v in zip(values, vectors.T):
        normal = tensor_to_voigt(np.outer(v, v))  # d(eigenvalue)/d(strain): a unit tensor v⊗v
        along = float(v @ voigt_to_tensor(d) @ v)
        if abs(value) > bounds.max_strain and along * value > 0:
            d -= 2.0 * along * normal
    trace = (strain + d)[:3].sum()
    if (trace > bounds.max_volumetric_extension and d[:3].sum() > 0) or \
            (trace < -bounds.max_volumetric_compaction and d[:3].sum() < 0):
        d[:3] -= 2.0 * d[:3].sum() / 3.0
    return d


def _proportional(rng, k, count, n_steps, increment, bounds, settings, name):
    n = rng.standard_normal(6)
    n /= np.linalg.norm(n)
    amplitude = rng.uniform(settings["min_amplitude_fraction"], 1.0) * bounds.largest_along(n)
    back = rng.uniform(0.0, settings["max_return_fraction"]) if rng.random() < settings["return_probability"] else 0.0
    n_up = min(n_steps, max(math.ceil(n_steps / 2), round(n_steps / (1.0 + back))))
    n_down = n_steps - n_up
    h = min(increment / np.abs(n).max(), amplitude / n_up)  # α per step: largest |Δε_ij| <= increment
    alpha = h * np.concatenate([np.arange(n_up + 1), n_up - np.arange(1, n_down + 1)])
    return alpha[:, None] * n[None, :], {"direction": n.tolist(), "amplitude": float(h * n_up),
                                          "return_fraction": n_down / n_up}


# ------------------------------------------------------------------------------ cost
def time_step_estimate(config: dict) -> float:
    """YADE's time step of a packing: timestep_safety · r_min · sqrt(ρ/E) (utils.PWaveTimeStep) for
    the smallest sphere the config allows; the real packing's is at least as long."""
    dem = config["dem"]
    return dem["timestep_safety"] * 0.5 * dem["diameter_min"] * math.sqrt(dem["density"] / dem["youngs_modulus"])


def cost_estimate(config: dict, paths: StrainPaths) -> dict:
    """RVE evaluations and (an upper bound of) the DEM particle-steps of driving the set: each
    increment takes the DEM steps of ``worker.steps_for_increment`` plus the one at rest."""
    dem = config["dem"]
    dt = time_step_estimate(config)
    dstrain = np.diff(paths.strain, axis=1)
    steps = np.array([[steps_for_increment(d, dt, dem["strain_rate"], dem["min_steps"], dem["max_steps"])
                       for d in trajectory] for trajectory in dstrain])
    dem_steps = np.where(steps > 0, steps + 1, 0)
    return {
        "set": paths.name,
        "trajectories": {f: int((paths.family == f).sum()) for f in FAMILIES},
        "n_steps": paths.n_steps,
        "rve_evaluations": int(dstrain.shape[0] * dstrain.shape[1]),
        "largest_increment": paths.largest_increment(),
        "time_step_estimate": dt,
        "dem_steps_per_evaluation": float(dem_steps.mean()),
        "particle_steps_estimate": float(dem_steps.sum() * dem["n_spheres"]),
        "n_spheres": int(dem["n_spheres"]),
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Cost of the RVE-path sets of a config (no DEM is run).")
    parser.add_argument("sets", nargs="*", help="set names (default: every set of rve_paths.sets)")
    parser.add_argument("--config", help="config file (default config/config.yaml)")
    args = parser.parse_args(argv)
    config = load_config(args.config)
    for name in args.sets or list(config["rve_paths"]["sets"]):
        print(json.dumps(cost_estimate(config, strain_paths_from_config(config, name)), indent=1))


if __name__ == "__main__":
    main()
