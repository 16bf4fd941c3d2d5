"""Conventional triaxial test on a hexahedral specimen (API stub; implementation follows).

    problem = TriaxialProblem.from_config(config)
    problem.n_gauss_points, problem.gp_positions          # [n_gp, 3]; gp = element * 8 + q
    ds = problem.run(material, load_path, method=..., checkpoint=None, logger=None, progress=True)
"""

from __future__ import annotations


class TriaxialProblem:
    @classmethod
    def from_config(cls, config: dict) -> "TriaxialProblem":
        raise NotImplementedError("TriaxialProblem is being implemented")

    @property
    def n_gauss_points(self) -> int:
        raise NotImplementedError

    @property
    def gp_positions(self):
        raise NotImplementedError

    def run(self, material, load_path, method="elastoplastic", checkpoint=None, logger=None, progress=True):
        raise NotImplementedError
