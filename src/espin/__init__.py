"""espin: virtual electrospun fiber mats and their mechanics.

Units inside espin: length um, stress MPa, force uN (= MPa um^2), time s, angles rad.
At the user-facing edge (configs, CLI, tables, plots) angles are in degrees.
"""

from __future__ import annotations

__version__ = "0.1.0"
