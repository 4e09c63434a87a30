"""Mechanics: an RVE pulled along a loading program (paper 3.1.2-3.2).

fiber law (:mod:`~espin.mechanics.fiber_law`, :mod:`~espin.mechanics.single_fiber`) ->
loading programs (:mod:`~espin.mechanics.loading`) -> assembly and linear solvers ->
equilibrium with the macroscopic tangent (:mod:`~espin.mechanics.equilibrium`) ->
homogenized stress (:mod:`~espin.mechanics.homogenization`) -> the program driver
(:mod:`~espin.mechanics.driver`) and ``simulate`` (:mod:`~espin.mechanics.run`), with the
results file, VTK series and figures.
"""
