"""The Fourier-signature baseline: a classical global-appearance localizer of the same
family as the eigenspace method, to hold it against.

Menegatti, Maeda and Ishiguro (Robotics and Autonomous Systems 47, 2004) describe a
panorama by the Fourier signature: the DFT of each image row, of which the first few
magnitudes are kept. Turning the robot shifts the panorama's columns cyclically, which
changes only the phases, so the magnitudes are a rotation-invariant descriptor, and the
phases give the turn. Payá, Fernández, Gil and Reinoso (Sensors 14, 2014, §3.1 and §5)
compare it with PCA-based descriptors for localization on indoor omnidirectional images:
nearest neighbour over the map's descriptors gives the position, the phase lag the heading.

Here a stop's full turn of ``N`` pinhole images at ``theta0 + 2 pi j / N`` stands for the
panorama: column ``j`` is the mean of image ``j``'s two central columns, so one column
step is one learned direction. Images are scaled to a mean of 0.5 first, as the
eigenspace's learning does (lighting).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from chizu.numeric.errors import InvalidInput
from chizu.numeric.geometry import wrap_angle

#: Fourier coefficients kept per row (the DC term and the first harmonics); Payá et al.
#: find localization saturating between 8 and 32 components on panoramas of 128 rows
COEFFICIENTS = 16
#: sub-steps per column step at which the phase correlation is evaluated for the heading
HEADING_SUBSTEPS = 8


def panorama(turn: np.ndarray) -> np.ndarray:
    """A turn of images ``(N, H, W)`` as a panorama ``(H, N)``: the two central columns
    of each image, averaged; brightness scaled to a mean of 0.5."""
    turn = np.asarray(turn, dtype=float)
    if turn.ndim != 3 or turn.shape[0] < 4 or turn.shape[2] < 2:
        raise InvalidInput(f"a turn is (N >= 4, H, W >= 2) images, got {turn.shape}",
                           field="images")
    w = turn.shape[2]
    cols = turn[:, :, (w - 1) // 2: w // 2 + 1].mean(axis=2)  # (N, H)
    mean = cols.mean()
    if mean > 0:
        cols = cols * (0.5 / mean)
    return cols.T


def signature(pano: np.ndarray, coefficients: int = COEFFICIENTS) -> np.ndarray:
    """The Fourier signature: the first ``coefficients`` DFT terms of each row
    ``(H, coefficients)``, complex (magnitudes describe, phases turn)."""
    spectrum = np.fft.rfft(pano, axis=1)
    return spectrum[:, :min(coefficients, spectrum.shape[1])]


@dataclass
class FourierMap:
    """The map: one signature per learning point ``(Nw, H, C)`` at ``points (Nw, 2)``, each
    learned from a turn whose first image faces ``heading0 (Nw,)``."""

    points: np.ndarray
    heading0: np.ndarray
    signatures: np.ndarray
    n_columns: int

    @staticmethod
    def learn(points: np.ndarray, heading0: np.ndarray, turns: np.ndarray,
              coefficients: int = COEFFICIENTS) -> FourierMap:
        """``turns (Nw, N, H, W)``: one full turn per learning point."""
        sigs = np.stack([signature(panorama(t), coefficients) for t in turns])
        return FourierMap(np.asarray(points, float), np.asarray(heading0, float), sigs,
                          int(turns.shape[1]))

    def localize(self, turn: np.ndarray) -> np.ndarray:
        """Pose ``(x, y, theta0)`` at the start of ``turn``: the position of the learning
        point with the nearest magnitude signature, the heading from the phase lag."""
        if turn.shape[0] != self.n_columns:
            raise InvalidInput(f"a turn of {self.n_columns} images is needed, got "
                               f"{turn.shape[0]}", field="images")
        q = signature(panorama(turn), self.signatures.shape[2])
        dist = np.linalg.norm(np.abs(self.signatures) - np.abs(q)[None], axis=(1, 2))
        best = int(np.argmin(dist))
        lag = phase_lag(q, self.signatures[best], self.n_columns)
        theta0 = self.heading0[best] + 2.0 * np.pi * lag / self.n_columns
        return np.array([*self.points[best], wrap_angle(theta0)])


def phase_lag(query: np.ndarray, ref: np.ndarray, n_columns: int) -> float:
    """The cyclic shift ``s`` (in columns, fractional) with ``query[j] = ref[j + s]``: the
    maximum of the cross-correlation ``Re sum_k Q_k conj(R_k) exp(-2 pi i k s / N)``
    over the kept coefficients (each harmonic counts twice, for its negative frequency)."""
    k = np.arange(query.shape[1])
    weight = np.where(k == 0, 1.0, 2.0)
    cross = (query * np.conj(ref)).sum(axis=0) * weight  # (C,)
    s = np.arange(n_columns * HEADING_SUBSTEPS) / HEADING_SUBSTEPS
    corr = np.real(np.exp(-2j * np.pi * np.outer(s, k) / n_columns) @ cross)
    return float(s[int(np.argmax(corr))])
