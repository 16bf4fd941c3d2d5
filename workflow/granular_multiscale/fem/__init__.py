"""Finite elements of the triaxial specimen: mesh, assembly, Newton solver, the triaxial problem."""
