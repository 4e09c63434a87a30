"""Geometry: from deposition parameters to the RVE's fiber network (paper 3.1).

orientation -> deposition (:mod:`~espin.geometry.deposition`, fibers as polylines in a
:class:`~espin.geometry.mat.FiberMat`) -> cross-links (:mod:`~espin.geometry.crosslinks`) ->
network (:mod:`~espin.geometry.network`) -> :class:`~espin.geometry.rve.RVE` (``generate``).
Beside them: statistics against measured targets (:mod:`~espin.geometry.statistics`,
:mod:`~espin.geometry.targets`, :mod:`~espin.geometry.fibers_csv`), and the RVE's files
(:mod:`~espin.geometry.rve_file`, :mod:`~espin.geometry.vtk`,
:mod:`~espin.geometry.figures`, :mod:`~espin.geometry.rve_folder`).
"""
