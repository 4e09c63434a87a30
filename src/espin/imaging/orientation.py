"""Orientation of the fibers in an image from its structure tensor (as OrientationJ).

The structure tensor J = sum over pixels of n n^T, n the unit gradient direction (Gaussian
derivatives, sigma 1 px), over the pixels whose gradient magnitude is above the image's
median (the fiber edges; flat areas carry only noise). Its main eigenvector is the mean
gradient direction, perpendicular to the fibers, so the dominant fiber direction is 90 deg
from it; the coherency (lambda_1 - lambda_2) / (lambda_1 + lambda_2) =
|J_xx - J_yy, 2 J_xy| / (J_xx + J_yy) is 0 for an isotropic image and 1 for perfectly
parallel fibers. OrientationJ weights each pixel by its squared gradient instead, so the
bright top layer of a mat dominates; with unit weights a dim deeper fiber counts as much as a
bright one, and on SEM-like images of aligned virtual mats the direction follows all visible
fibers (docs/sem.md). Angles are counter-clockwise from +x with y up (rows grow downwards),
in [0, 180) deg.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = ["structure_tensor_orientation", "local_orientation", "image_angle_deg"]


def structure_tensor_orientation(image: np.ndarray, sigma_px: float = 1.0) -> tuple[float, float]:
    """Dominant fiber direction [deg] and coherency [-] of an image.

    Parameters
    ----------
    image : (rows, cols) float64
        Grey levels (fibers bright or dark: the tensor does not care).
    sigma_px : float [px]
        Gaussian derivative scale.

    Returns
    -------
    direction_deg : float [deg]
        Dominant fiber axis, in [0, 180).
    coherency : float
        In [0, 1].
    """
    d_row = ndimage.gaussian_filter(image, sigma_px, order=(1, 0))
    d_col = ndimage.gaussian_filter(image, sigma_px, order=(0, 1))
    gx, gy = d_col, -d_row  # x right, y up
    magnitude = np.hypot(gx, gy)
    edge = magnitude > np.median(magnitude)
    if not edge.any():
        return float("nan"), 0.0
    nx, ny = gx[edge] / magnitude[edge], gy[edge] / magnitude[edge]
    jxx, jyy, jxy = float(np.sum(nx * nx)), float(np.sum(ny * ny)), float(np.sum(nx * ny))
    trace = jxx + jyy
    if trace <= 0:
        return float("nan"), 0.0
    gradient = 0.5 * np.arctan2(2.0 * jxy, jxx - jyy)
    coherency = float(np.hypot(jxx - jyy, 2.0 * jxy) / trace)
    return float(np.degrees(np.mod(gradient + np.pi / 2.0, np.pi))), coherency


def local_orientation(image: np.ndarray, window_px: float, sigma_px: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Local fiber direction and coherency at every pixel (OrientationJ's local structure
    tensor).

    The products of the Gaussian derivatives (scale ``sigma_px``) are averaged by a Gaussian
    window of sigma ``window_px``, J = G * (g g^T), each pixel weighted by its squared gradient
    as OrientationJ does (locally, a bright fiber edge should steer the direction).

    Parameters
    ----------
    image : (rows, cols) float64
        Grey levels.
    window_px : float [px]
        Sigma of the averaging window (about a fiber width: the direction along a fiber).
    sigma_px : float [px]
        Gaussian derivative scale.

    Returns
    -------
    direction_deg : (rows, cols) float64 [deg]
        Local fiber axis, counter-clockwise from +x with y up, in [0, 180).
    coherency : (rows, cols) float64
        (lambda_1 - lambda_2) / (lambda_1 + lambda_2) of the local tensor, in [0, 1]; 0 where
        the image is flat.
    """
    d_row = ndimage.gaussian_filter(image, sigma_px, order=(1, 0))
    d_col = ndimage.gaussian_filter(image, sigma_px, order=(0, 1))
    gx, gy = d_col, -d_row  # x right, y up
    jxx, jyy, jxy = (ndimage.gaussian_filter(a, window_px) for a in (gx * gx, gy * gy, gx * gy))
    trace = jxx + jyy
    anisotropy = np.hypot(jxx - jyy, 2.0 * jxy)
    with np.errstate(invalid="ignore", divide="ignore"):
        coherency = np.where(trace > 1e-12 * trace.max(initial=0.0), anisotropy / trace, 0.0)
    gradient = 0.5 * np.arctan2(2.0 * jxy, jxx - jyy)
    direction = np.degrees(np.mod(gradient + np.pi / 2.0, np.pi))
    return np.where(direction >= 180.0, 0.0, direction), np.clip(coherency, 0.0, 1.0)


def image_angle_deg(d_row: np.ndarray, d_col: np.ndarray) -> np.ndarray:
    """Axis [deg, in [0, 180)] of image vectors (d_row, d_col), counter-clockwise from +x."""
    return np.degrees(np.mod(np.arctan2(-np.asarray(d_row), np.asarray(d_col)), np.pi))
