"""Imaging: measuring electrospun fiber mats on SEM images, and calibrating geometry to them.

- :mod:`~espin.imaging.measurement` (``espin measure``): :func:`measure` ->
  :class:`SEMMeasurement`: scale (given, or from the scale bar,
  :mod:`~espin.imaging.scale`), fiber segmentation (:mod:`~espin.imaging.segment`), tracing
  through crossings (:mod:`~espin.imaging.trace`), local diameters
  (:mod:`~espin.imaging.widths`), orientation (:mod:`~espin.imaging.orientation`: structure
  tensor, per-fiber end-to-end axes), tortuosity (contour / end-to-end length, paper section
  2.2), fitted distributions (:mod:`~espin.imaging.distributions`); ``.write(folder)`` writes
  ``fibers.csv`` (format in :mod:`espin.geometry.fibers_csv`), ``measurement.toml``,
  ``histograms.png`` and ``overlay.png`` (:mod:`~espin.imaging.figures`).
- :mod:`~espin.imaging.synthetic`: :func:`render_sem` -> :class:`SyntheticSEM`, an SEM-like
  image of a virtual mat with its ground truth.
- :mod:`espin.imaging.geometry_calibration` (``espin calibrate-geometry``): deposition
  parameters whose virtual mat matches measured distributions.
"""
