"""Which held-out Gauss points the stress–strain figures show (paper Figs. 11–13).

The rule, stated so a reader can check it: among the Gauss points held out of training,
take the one nearest to each of three anchor points of the specimen's bounding box
[x0, x1] × [y0, y1] × [z0, z1] (z axial, the top platen at z1):

* ``corner``  — near a platen corner: the top corner (x1, y1, z1);
* ``centre``  — the centre of the specimen;
* ``surface`` — mid-height on a lateral surface: (x1, (y0+y1)/2, (z0+z1)/2).

Ties go to the lower Gauss-point index; the three points are distinct (a point already
taken is skipped).

The load steps of the field figures are chosen in the config too (``resolve_steps``).
"""

from __future__ import annotations

import numpy as np

ANCHORS = ("corner", "centre", "surface")

DESCRIPTIONS = {
    "corner": "near the top platen corner (x1, y1, z1)",
    "centre": "at the centre of the specimen",
    "surface": "mid-height on the lateral surface x = x1",
}


def anchor_positions(lower: np.ndarray, upper: np.ndarray) -> dict[str, np.ndarray]:
    lower = np.asarray(lower, dtype=float)
    upper = np.asarray(upper, dtype=float)
    centre = 0.5 * (lower + upper)
    return {
        "corner": upper.copy(),
        "centre": centre,
        "surface": np.array([upper[0], centre[1], centre[2]]),
    }


def select_gauss_points(gp_position: np.ndarray, candidates, lower, upper) -> dict[str, int]:
    """Gauss-point index per anchor (see the module docstring).

    gp_position: [n_gp, 3]; candidates: indices of the held-out Gauss points;
    lower/upper: corners of the specimen's bounding box.
    """
    gp_position = np.asarray(gp_position, dtype=float)
    candidates = np.unique(np.asarray(candidates, dtype=int))
    if candidates.size < len(ANCHORS):
        raise ValueError(
            f"need at least {len(ANCHORS)} held-out Gauss points to pick from, got {candidates.size}"
        )
    if candidates.min() < 0 or candidates.max() >= len(gp_position):
        raise ValueError(f"held-out Gauss point index out of range 0..{len(gp_position) - 1}")
    chosen: dict[str, int] = {}
    for name, anchor in anchor_positions(lower, upper).items():
        distance = np.linalg.norm(gp_position[candidates] - anchor, axis=1)
        for k in np.lexsort((candidates, distance)):
            if int(candidates[k]) not in chosen.values():
                chosen[name] = int(candidates[k])
                break
    return chosen


def resolve_steps(steps, n_steps: int) -> list[int]:
    """Config steps (negative counts from the end: -1 = last) -> valid step numbers."""
    resolved = []
    for s in steps:
        k = int(s) if int(s) >= 0 else n_steps + int(s)
        if not 0 <= k < n_steps:
            raise ValueError(f"config key 'analysis.field_steps': step {s} is outside the run's steps 0..{n_steps - 1}")
        resolved.append(k)
    return resolved
