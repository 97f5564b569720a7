"""Position by interpolation (paper §2.2, eqs. 4-5).

The query projection x' is projected onto the plane through x'_1, x'_2, x'_3
(affine: k1 + k2 + k3 = 1, least squares), ``x'_p = sum k_i x'_i`` (eq. 4), and the
pose is ``s = sum k_i s_i`` (eq. 5) with theta interpolated on the circle (offsets
from theta_1 wrapped to (-pi, pi] before weighting).
"""

from __future__ import annotations

import numpy as np

from chizu.numeric.geometry import wrap_angle


def affine_weights(x: np.ndarray, x3: np.ndarray) -> np.ndarray:
    """Eq. 4: weights ``(..., 3)`` (summing to 1) of the point of the plane through
    ``x3 (..., 3, K)`` nearest to ``x (..., K)``.

    Solves ``x - x'_3 = k1 (x'_1 - x'_3) + k2 (x'_2 - x'_3)`` by least squares via the
    2x2 normal equations (batched); degenerate planes fall back to the pseudo-inverse.
    """
    x = np.asarray(x, dtype=float)
    x3 = np.asarray(x3, dtype=float)
    a = np.stack([x3[..., 0, :] - x3[..., 2, :], x3[..., 1, :] - x3[..., 2, :]], axis=-1)
    rhs = x - x3[..., 2, :]
    ata = np.einsum("...ki,...kj->...ij", a, a)
    atb = np.einsum("...ki,...k->...i", a, rhs)
    k12 = np.einsum("...ij,...j->...i", np.linalg.pinv(ata), atb)
    return np.concatenate([k12, 1.0 - k12.sum(axis=-1, keepdims=True)], axis=-1)


def interpolate_pose(weights: np.ndarray, s3: np.ndarray) -> np.ndarray:
    """Eq. 5: pose ``(..., 3)`` = sum k_i s_i for ``s3 (..., 3, 3)``, theta on the circle."""
    k = np.asarray(weights, dtype=float)
    s3 = np.asarray(s3, dtype=float)
    out = np.empty(k.shape[:-1] + (3,))
    out[..., :2] = np.einsum("...i,...ij->...j", k, s3[..., :2])
    th1 = s3[..., 0, 2]
    off = wrap_angle(s3[..., :, 2] - th1[..., None])
    out[..., 2] = wrap_angle(th1 + np.sum(k * off, axis=-1))
    return out
