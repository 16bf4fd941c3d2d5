"""Shear-band metrics of a plane-strain run, from its Gauss-point strains (pure numpy).

    metrics = band_metrics(run)            # a biaxial run file's Dataset; the last step by default

The measure is the equivalent shear strain ε_s = sqrt(2/3 e:e) of the total strain at each
Gauss point (``quantities.equivalent_shear_strain``; plane strain, so ε_zz = 0 enters e).
Every Gauss point weighs the same (the biaxial mesh is uniform).

* **The band**: the straight strip through the specimen that holds the most shear strain above
  the specimen mean. For every direction θ (0.5° apart) and every offset c of the line
  x·n(θ) = c (n the line's normal), the score is Σ (ε_s,i − mean ε_s) over the points within
  half a strip width of the line; the best (θ, c) is the band's centre line. The strip starts
  one Gauss-point spacing wide and takes the measured width twice more (a strip narrower than
  the band could turn inside it).
* **Inclination**: the angle between the band and the direction of the minor principal stress
  (the least compressive; in biaxial compression the lateral direction) of the specimen's mean
  in-plane stress at that step, in [0°, 90°]. Mohr–Coulomb puts it at 45° + φ/2, Roscoe's
  zero-extension direction at 45° + ψ/2.
* **Width**: √12 times the standard deviation, across the centre line, of the strain excess
  (ε_s − mean, where positive) of the points within a third of the specimen width of the
  line: the width of a top-hat profile with the same second moment.
* **Band points**: those within half the width (and at least half a spacing) of the line.
* **Ratio**: mean ε_s of the band points over the specimen's mean, at the step.
* **Onset**: the first load at which the band points' mean ε_s reaches ``onset_ratio`` (2) times
  the specimen mean, the band points being those of the measured step; interpolated linearly
  between load steps. NaN where it never does.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from .quantities import equivalent_shear_strain

ONSET_RATIO = 2.0
ANGLES = np.arange(0.0, 180.0, 0.5)


def shear_strain(run: xr.Dataset, step: int) -> np.ndarray:
    """[n_gp] equivalent shear strain of the run's total strain at a step."""
    return equivalent_shear_strain(run["strain"].isel(step=step).transpose("gp", "comp").values)


def _spacing(xy: np.ndarray) -> float:
    """Typical distance between neighbouring Gauss points (median nearest-neighbour distance)."""
    d = np.linalg.norm(xy[:, None, :] - xy[None, :, :], axis=-1)
    np.fill_diagonal(d, np.inf)
    return float(np.median(d.min(axis=1)))


def centre_line(xy: np.ndarray, strain: np.ndarray, half_width: float) -> tuple[float, float, float]:
    """(θ in degrees, offset c, score) of the strip |x·n(θ) − c| ≤ half_width with the largest Σ (ε_s − mean)."""
    excess = strain - strain.mean()
    best = (0.0, 0.0, -np.inf)
    for theta in ANGLES:
        t = np.radians(theta)
        s = xy @ np.array([-np.sin(t), np.cos(t)])  # signed distance along the normal
        # a line through every point (the optimal strip is centred near one); the strip sums from
        # cumulative sums over the points sorted by distance
        order = np.argsort(s)
        s_sorted = s[order]
        cumulative = np.concatenate([[0.0], np.cumsum(excess[order])])
        lo = np.searchsorted(s_sorted, s_sorted - half_width, side="left")
        hi = np.searchsorted(s_sorted, s_sorted + half_width, side="right")
        scores = cumulative[hi] - cumulative[lo]
        k = int(np.argmax(scores))
        if scores[k] > best[2]:
            best = (float(theta), float(s_sorted[k]), float(scores[k]))
    return best


def _width(xy: np.ndarray, strain: np.ndarray, theta: float, offset: float, reach: float) -> float:
    """√12 × the standard deviation, across the line, of the positive strain excess within `reach` of it."""
    t = np.radians(theta)
    distance = xy @ np.array([-np.sin(t), np.cos(t)]) - offset
    excess = np.clip(strain - strain.mean(), 0.0, None) * (np.abs(distance) <= reach)
    return float(np.sqrt(12.0 * np.sum(excess * distance**2) / excess.sum())) if excess.sum() > 0 else 0.0


def minor_principal_direction(stress: np.ndarray) -> np.ndarray:
    """Unit vector (x, z) of the least compressive in-plane principal stress of the mean stress [n_gp, 6]."""
    mean = stress.mean(axis=0)
    tensor = np.array([[mean[0], mean[4]], [mean[4], mean[2]]])  # σxx, σxz, σzz
    values, vectors = np.linalg.eigh(tensor)
    return vectors[:, int(np.argmax(values))]  # tension positive: the largest is the least compressive


def band_metrics(run: xr.Dataset, step: int = -1, onset_ratio: float = ONSET_RATIO) -> dict:
    """The band of a plane-strain run at `step` (see the module docstring); lengths in m, angles in degrees."""
    n_steps = run.sizes["step"]
    step = step % n_steps
    xy = run["gp_position"].transpose("gp", "xyz").values[:, [0, 2]]  # the plane of the body: x, z
    strain = shear_strain(run, step)
    spacing = _spacing(xy)
    reach = float(np.ptp(xy[:, 0]) + spacing) / 3.0
    half = 0.5 * spacing
    for _ in range(3):
        theta, offset, _ = centre_line(xy, strain, half)
        width = _width(xy, strain, theta, offset, reach)
        half = max(0.5 * width, 0.5 * spacing)
    t = np.radians(theta)
    direction, normal = np.array([np.cos(t), np.sin(t)]), np.array([-np.sin(t), np.cos(t)])
    distance = xy @ normal - offset
    in_band = np.abs(distance) <= max(0.5 * width, 0.5 * spacing)
    stress = run["stress"].isel(step=step).transpose("gp", "comp").values
    minor = minor_principal_direction(stress)
    inclination = float(np.degrees(np.arccos(min(1.0, abs(float(direction @ minor))))))
    # the band points' mean over the specimen's at every step: the onset
    all_strain = equivalent_shear_strain(run["strain"].transpose("step", "gp", "comp").values)
    specimen_mean = all_strain.mean(axis=1)
    ratio = np.divide(all_strain[:, in_band].mean(axis=1), specimen_mean, out=np.full(n_steps, np.nan),
                      where=specimen_mean > 0)
    load = _load(run)
    onset = _first_crossing(load[: step + 1], ratio[: step + 1], onset_ratio)
    return {
        "step": int(step),
        "load": float(load[step]),
        "inclination_deg": inclination,
        "band_angle_from_x_deg": float(theta),
        "minor_principal_angle_from_x_deg": float(np.degrees(np.arctan2(minor[1], minor[0])) % 180.0),
        "width_m": width,
        "gauss_point_spacing_m": spacing,
        "band_points": int(in_band.sum()),
        "gauss_points": int(xy.shape[0]),
        "band_ratio": float(ratio[step]),
        "onset_load": onset,
        "onset_ratio": float(onset_ratio),
        "mean_shear_strain": float(specimen_mean[step]),
        "band_shear_strain": float(all_strain[step, in_band].mean()),
        "max_shear_strain": float(strain.max()),
        "band_gauss_points": np.flatnonzero(in_band).tolist(),
        "ratio_per_step": ratio.tolist(),
    }


def _load(run: xr.Dataset) -> np.ndarray:
    """The load path's value per step: the axial strain of a platen test, else load_displacement."""
    if "axial_strain" in run:
        return run["axial_strain"].values.astype(float)
    return run["load_displacement"].values.astype(float)


def _first_crossing(x: np.ndarray, y: np.ndarray, level: float) -> float:
    """First x at which y reaches level (linear between samples); NaN if never."""
    above = np.flatnonzero(np.nan_to_num(y, nan=-np.inf) >= level)
    if not above.size:
        return float("nan")
    k = int(above[0])
    if k == 0 or not np.isfinite(y[k - 1]):
        return float(x[k])
    return float(x[k - 1] + (level - y[k - 1]) / (y[k] - y[k - 1]) * (x[k] - x[k - 1]))
