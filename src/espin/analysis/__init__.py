"""Analysis of curves: properties (:mod:`~espin.analysis.properties`), experimental curves
(:mod:`~espin.analysis.experiments`) and calibration of the fiber parameters to them
(:mod:`espin.analysis.calibration`, ``espin fit``)."""
