"""Studies over many simulations: ensembles of tensile tests (:mod:`~espin.studies.ensemble`),
RVE-size studies and parameter sweeps (:mod:`~espin.studies.sweeps`), and the DOF study
(:mod:`~espin.studies.dof`), with their figures."""
