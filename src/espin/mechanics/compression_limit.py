"""Compression limit of the fiber segments: an opt-in stiff contact that keeps every element
from shortening below a share of its deposited chord.

In the paper's model a compressed element resists with the slack modulus E_b (a wrinkled
fiber, E_t / 1000 for plla) down to zero length and, past it, comes out on the other side: two
cross-links of a fiber can pass through each other. With fused crossings
(:mod:`espin.mechanics.crossings`) under lateral ``free``, the welds' torques act on short
elements (a third of plla's elements are shorter than a fiber diameter) through lever arms of
a fraction of a micrometre and crush them step after step; the predictor then carries one
through zero length, its joints flip by 180 deg and Newton does not come back (docs/mechanics.md,
"Fused crossings"). A real segment cannot do that: once its chord has shrunk to a fraction of
its deposited length it has folded onto itself, and its end junctions press on the fiber's own
material.

With ``fiber.compression_limit`` = lambda_c in (0, 1), an element of stretch lambda = l / l0
below lambda_c carries, on top of its fiber law, the contact force

    T_c = A E_t (1 - lambda_c / lambda)    (compressive; 0 at lambda >= lambda_c),

A its reference area, E_t the taut modulus (the fiber's material): the energy
A l0 E_t (lambda - lambda_c - lambda_c ln(lambda / lambda_c)) >= 0, C1 at lambda_c, grows
without bound as lambda -> 0, so no equilibrium passes an element through zero length. Its
stiffness dT_c / dl = A E_t lambda_c / (l0 lambda^2) is positive, so the term keeps a positive
semi-definite tangent positive semi-definite. The force adds to the element's axial force, so
it enters the potential's gradient, the tangents and the homogenized stresses as the fiber
law does; it is elastic and independent of the plastic state. lambda_c = 0 (default) adds
nothing: the paper's model. docs/model.md section 3.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from espin.mechanics.fiber_law import STRETCH_FLOOR

__all__ = ["CompressionLimit"]


@dataclass(frozen=True)
class CompressionLimit:
    """The contact force of elements compressed below a share of their deposited chord.

    Attributes
    ----------
    stretch : float
        lambda_c in (0, 1): the stretch l / l0 below which the contact acts.
    modulus_MPa : float [MPa]
        Its modulus (the taut modulus E_t), > 0.
    """

    stretch: float
    modulus_MPa: float

    def __post_init__(self) -> None:
        if not 0.0 < self.stretch < 1.0:
            raise ValueError(f"CompressionLimit.stretch must be in (0, 1), got {self.stretch!r}")
        if not (self.modulus_MPa > 0.0 and np.isfinite(self.modulus_MPa)):
            raise ValueError(f"CompressionLimit.modulus_MPa must be finite and > 0, got {self.modulus_MPa!r}")

    def add(
        self, force: np.ndarray, stiffness: np.ndarray, stretch: np.ndarray, area: np.ndarray, l0: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The element forces [uN] and stiffnesses dT/dl [uN / um] with the contact added.

        Parameters
        ----------
        force, stiffness : (n,) float64
            The fiber law's axial force T [uN] and dT/dl [uN / um].
        stretch : (n,) float64
            lambda = l / l0 (evaluated at ``STRETCH_FLOOR`` below it, like the fiber law).
        area, l0 : (n,) float64
            Reference area [um^2] and length [um].

        Returns
        -------
        tuple of (n,) float64
            New arrays; unchanged where lambda >= lambda_c.
        """
        lam = np.maximum(stretch, STRETCH_FLOOR)
        active = lam < self.stretch
        scale = area * self.modulus_MPa
        contact = np.where(active, scale * (1.0 - self.stretch / lam), 0.0)
        slope = np.where(active, scale * self.stretch / (l0 * lam * lam), 0.0)
        return force + contact, stiffness + slope
