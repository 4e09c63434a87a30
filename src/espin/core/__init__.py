"""Core: what every stage uses, and nothing of any stage.

- :mod:`~espin.core.config`: the one validated config (``rve``, ``fiber``, ``loading``,
  ``solver``, ``output``) and the built-in presets (:mod:`espin.core.presets`, ``plla``);
- :mod:`~espin.core.errors`: espin's exception types;
- :mod:`~espin.core.atomic`, :mod:`~espin.core.header`, :mod:`~espin.core.figures`: atomic
  file writes, the header of every espin HDF5 file, PNG figures written atomically;
- :mod:`~espin.core.parallel`, :mod:`~espin.core.cluster`: the task pool (local processes,
  Dask) and batch-system clusters.
"""
