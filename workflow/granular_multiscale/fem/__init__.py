"""Finite elements: meshes, Gauss-point operators, the Newton solver and the boundary-value
problems on one base (``problem.py``): the triaxial specimen, the plane-strain biaxial test and
the strip footing.

    problem = make_problem(config, "biaxial")      # or "triaxial", "footing"
"""

from __future__ import annotations

PROBLEMS = ("triaxial", "biaxial", "footing")


def problem_class(name: str):
    """The class of problem `name`, or ValueError naming the config key."""
    from .biaxial import BiaxialProblem
    from .footing import FootingProblem
    from .triaxial import TriaxialProblem

    classes = {"triaxial": TriaxialProblem, "biaxial": BiaxialProblem, "footing": FootingProblem}
    if name not in classes:
        raise ValueError(f"config key 'problems': unknown problem {name!r}; known: {list(PROBLEMS)}")
    return classes[name]


def make_problem(config: dict, name: str = "triaxial"):
    """Problem `name` with the settings of its config section (triaxial: ``specimen``) and ``newton``."""
    return problem_class(name).from_config(config)
