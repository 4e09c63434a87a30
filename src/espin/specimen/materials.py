"""Materials at the quadrature points of the specimen: what the macro Newton asks of them.

A material holds one state per quadrature point. The macro solver asks for the nominal stress
P and its algorithmic tangent A = dP/dF at trial deformation gradients (:meth:`evaluate`, from
the committed state over the time step to ``time``), then either :meth:`commit` s the last
trial (the macro step converged) or :meth:`rollback` s it (the step is cut). Index convention
P_iJ (i spatial, J reference), A_iJkL = dP_iJ / dF_kL; units MPa.

:class:`NeoHookean` is the closed-form material that validates the finite elements alone
(patch test, tangent, mesh convergence): a compressible neo-Hookean membrane with the in-plane
F only (no thickness update),

    W(F) = mu / 2 (tr C - 2 - 2 ln J) + lambda / 2 (ln J)^2,   C = F^T F,  J = det F,

so P = mu (F - F^-T) + lambda ln J F^-T. Its small-strain limit is 2-D isotropic elasticity
with shear modulus mu and 2-D bulk modulus lambda + mu: under uniaxial stress the modulus is
4 mu (lambda + mu) / (lambda + 2 mu) and Poisson's ratio lambda / (lambda + 2 mu).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from espin.core.errors import ConfigError, InadmissibleState

__all__ = ["PointMaterial", "NeoHookean"]


class PointMaterial(Protocol):
    """The interface of a material at ``n_points`` quadrature points."""

    n_points: int
    symmetric_tangent: bool
    """True when A has the major symmetry A_iJkL = A_kLiJ (a hyperelastic material, or RVEs whose
    step minimizes a potential): the macro tangent is then solved by espin's symmetric solvers."""

    def evaluate(self, F: np.ndarray, time: float) -> tuple[np.ndarray, np.ndarray]:
        """Trial P (n, 2, 2) [MPa] and A (n, 2, 2, 2, 2) [MPa] at F (n, 2, 2) and ``time`` [s].

        A state the material cannot follow raises :class:`~espin.core.errors.StepNotConverged`
        (:class:`~espin.core.errors.InadmissibleState` for det F <= 0; a point's solve failing):
        the macro step is cut.
        Any other exception is a bug and stops the run."""

    def time_error(self) -> float:
        """Relative local time-integration error of the last trial (0 for a rate-independent material)."""

    def commit(self) -> None:
        """The last trial becomes the points' state."""

    def rollback(self) -> None:
        """Forget the trials since the last commit."""

    def fields(self) -> dict[str, np.ndarray]:
        """Per-point scalars of the committed state (e.g. yielded fraction), each (n,)."""


class NeoHookean:
    """Compressible neo-Hookean membrane (module docstring); elastic, so no history.

    Parameters
    ----------
    n_points
        Quadrature points.
    shear_modulus_MPa
        mu > 0 [MPa].
    lame_MPa
        lambda >= 0 [MPa] (the 2-D first Lame parameter).
    """

    def __init__(self, n_points: int, shear_modulus_MPa: float, lame_MPa: float) -> None:
        if not shear_modulus_MPa > 0.0:
            raise ConfigError(f"shear_modulus_MPa = {shear_modulus_MPa}: must be > 0 MPa")
        if not lame_MPa >= 0.0:
            raise ConfigError(f"lame_MPa = {lame_MPa}: must be >= 0 MPa")
        self.n_points = n_points
        self.symmetric_tangent = True
        self.mu = float(shear_modulus_MPa)
        self.lam = float(lame_MPa)

    @classmethod
    def from_uniaxial(cls, n_points: int, modulus_MPa: float, poisson_ratio: float) -> NeoHookean:
        """The material with small-strain uniaxial-stress modulus E [MPa] and in-plane
        Poisson ratio nu in [0, 1)."""
        if not 0.0 <= poisson_ratio < 1.0:
            raise ConfigError(f"poisson_ratio = {poisson_ratio}: must be in [0, 1)")
        if not modulus_MPa > 0.0:
            raise ConfigError(f"modulus_MPa = {modulus_MPa}: must be > 0 MPa")
        mu = modulus_MPa / (2.0 * (1.0 + poisson_ratio))
        return cls(n_points, mu, 2.0 * mu * poisson_ratio / (1.0 - poisson_ratio))

    def evaluate(self, F: np.ndarray, time: float) -> tuple[np.ndarray, np.ndarray]:
        J = np.linalg.det(F)
        if np.any(J <= 0.0):
            raise InadmissibleState(f"det F <= 0 at {int(np.sum(J <= 0.0))} point(s)")
        inv = np.linalg.inv(F)  # F^-1, [n, L, i]
        inv_T = np.swapaxes(inv, 1, 2)  # F^-T, [n, i, L]
        log_J = np.log(J)[:, None, None]
        P = self.mu * (F - inv_T) + self.lam * log_J * inv_T
        eye = np.eye(2)
        A = (
            self.mu * np.einsum("ik,JL->iJkL", eye, eye)[None]
            + (self.mu - self.lam * log_J[..., None, None]) * np.einsum("nLi,nJk->niJkL", inv, inv)
            + self.lam * np.einsum("nJi,nLk->niJkL", inv, inv)
        )
        return P, A

    def time_error(self) -> float:
        return 0.0

    def commit(self) -> None:
        pass

    def rollback(self) -> None:
        pass

    def fields(self) -> dict[str, np.ndarray]:
        return {}
