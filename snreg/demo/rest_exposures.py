"""The sensor noise of a rest: each frame a left and a right exposure drawn apart, so the store window sees fresh noise.

Why: a real camera's noise is new in every frame, so the spread of a store window of 60 fixes measures the tracker's
noise, and a window that slides on meets new draws. The demo's scenes render each rest once (the ray casting costs
~0.1 s a pair, 0.4 s before issue 36) and used to replay ``noise_variants`` exposures of it in turn, left and right
together: with 3, the window held 3 fixes repeated, its spread that of 3 draws (chi-square on 2 degrees of freedom:
half again or half the true value), and the same on every visit of the rest. Issue 35: the surgery demo's node at the
148 mm rest (depth 118 mm, per-fix spread 0.91 mm over 12 independent exposures) showed 1.27-1.70 mm on every rest and
was never auto-stored. Here the rest's noise-free radiance is exposed ``variants`` times, and frame ``index`` pairs
left exposure ``index % K`` with right exposure ``(index % K + index // K) % K``: K * K pairs, each once in K * K
frames, whose fixes differ (the depth's error is the two eyes' disparity error), for the cost of 2K exposures (~10 ms
each) and no more ray casting.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["RestExposures"]


class RestExposures:
    """``variants`` exposures of each eye of one rest's radiance; :meth:`pair` gives frame ``index``'s pair.

    ``expose(radiance, seed)``: (left, right) uint8 frames of the radiance with noise drawn under ``seed``."""

    def __init__(self, radiance: tuple[np.ndarray, np.ndarray], expose: Callable[[tuple, int], tuple], variants: int,
                 seed: int):
        if variants < 1:
            raise ValueError(f"a rest needs at least 1 exposure, not {variants}")
        exposed = [expose(radiance, seed + k) for k in range(variants)]
        self.lefts = [pair[0] for pair in exposed]
        self.rights = [pair[1] for pair in exposed]

    @property
    def variants(self) -> int:
        return len(self.lefts)

    def choice(self, index: int) -> tuple[int, int]:
        """(left exposure, right exposure) of frame ``index``: every combination once in ``variants ** 2`` frames."""
        k = self.variants
        return index % k, (index % k + index // k) % k

    def pair(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        left, right = self.choice(index)
        return self.lefts[left], self.rights[right]
