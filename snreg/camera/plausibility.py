"""Is a stereo calibration's content plausible, and does its given rectification follow from its cameras?

Why: a calibration file is a list of numbers, and OpenCV computes with whatever it is given: an image 10^9 pixels
wide allocates terabytes, a baseline of 10^200 mm overflows, and a rectification copied from another calibration
(``Q`` or ``P1`` all zeros, or a horizontal rectification beside a vertical ``T``) tracks every tip millimetres off
without a word. The bounds below are far beyond any endoscope or stereo rig; the rectification checks are the
properties ``cv2.stereoRectify`` guarantees (thesis §4.2; OpenCV's ``stereoRectify`` documentation):

- ``R1`` and ``R2`` are rotations; ``R1`` turns the baseline (the right camera's centre in the left camera's frame,
  ``-R^T T``) onto the rectified x axis (horizontal rectification) or y axis (vertical);
- ``P1``, ``P2`` are projections ``[K' | 0]`` and ``[K' | K' b]`` with positive focal lengths, ``b`` the rectified
  baseline along that same axis, its length ``|T|``;
- ``Q`` is the reprojection matrix of those two: ``Q[0,3] = -cx``, ``Q[1,3] = -cy``, ``Q[2,3] = f`` and
  ``Q[3,2] = -1/b``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["check_bounds", "check_rectification", "MAX_IMAGE_PX", "MAX_BASELINE_MM", "MAX_FOCAL_PX",
           "MAX_DISTORTION", "AXIS_TOLERANCE_DEG"]

MAX_IMAGE_PX = 32768          # per side: 16K video is 15360 px wide
MAX_BASELINE_MM = 2000.0      # a stereo endoscope has ~4-5 mm, a stereo rig on a stand well under 2 m
MAX_FOCAL_PX = 1e6
MAX_DISTORTION = 1e4          # OpenCV's rational model stays within tens; beyond this undistortion diverges
AXIS_TOLERANCE_DEG = 1.0      # stereoRectify aligns the baseline exactly; 1 degree allows for rounding in files
_RELATIVE = 0.01


def check_bounds(size: tuple[int, int], values: dict[str, np.ndarray]) -> None:
    """ValueError naming the value out of any plausible range (image size, focal lengths, distortion, baseline)."""
    if max(size) > MAX_IMAGE_PX:
        raise ValueError(f"the image size {size[0]}x{size[1]} is beyond any camera ({MAX_IMAGE_PX} px a side at most)")
    for name in ("K1", "K2"):
        K = values[name]
        if max(abs(K[0, 0]), abs(K[1, 1]), abs(K[0, 2]), abs(K[1, 2])) > MAX_FOCAL_PX:
            raise ValueError(f"{name} holds values beyond {MAX_FOCAL_PX:g} px: not a camera matrix")
    for name in ("D1", "D2"):
        if np.abs(values[name]).max() > MAX_DISTORTION:
            raise ValueError(f"{name} holds a coefficient beyond {MAX_DISTORTION:g}: not a lens distortion")
    largest = float(np.abs(values["T"]).max())
    with np.errstate(over="ignore"):
        baseline = float(np.linalg.norm(values["T"]))
    if not baseline <= MAX_BASELINE_MM:
        raise ValueError(f"T puts the cameras more than {largest:.3g} mm apart; a stereo baseline is at most "
                         f"{MAX_BASELINE_MM:g} mm: check T's units (mm)")


def check_rectification(values: dict[str, np.ndarray]) -> None:
    """ValueError when the given ``R1 R2 P1 P2 Q`` do not follow from ``R`` and ``T`` (module docstring), saying which
    property fails."""
    for name in ("R1", "R2"):
        M = values[name]
        if np.abs(M @ M.T - np.eye(3)).max() > 1e-3 or np.linalg.det(M) < 0:
            raise ValueError(f"{name} is not a rotation matrix")
    for name in ("P1", "P2"):
        P = values[name]
        if not (P[0, 0] > 0 and P[1, 1] > 0) or not np.allclose(P[2], [0, 0, 1, 0], atol=1e-9):
            raise ValueError(f"{name} is not a rectified projection: its focal lengths must be positive (got "
                             f"{P[0, 0]:g}, {P[1, 1]:g}) and its last row 0 0 1 0")
    P1, P2, Q = values["P1"], values["P2"], values["Q"]
    if abs(P1[0, 3]) > 1e-6 * P1[0, 0] or abs(P1[1, 3]) > 1e-6 * P1[1, 1]:
        raise ValueError("P1 is not the left rectified projection (its last column must be zero)")
    T = values["T"].ravel()
    centre = -values["R"].T @ T
    rectified = values["R1"] @ (centre / np.linalg.norm(centre))
    axis = int(np.argmax(np.abs(rectified[:2])))
    angle = np.degrees(np.arccos(min(1.0, abs(float(rectified[axis])))))
    if angle > AXIS_TOLERANCE_DEG:
        raise ValueError(f"R1 does not turn the baseline (-R^T T) onto the rectified x or y axis ({angle:.1f} degrees "
                         "off): the rectification belongs to other cameras")
    given = P2[axis, 3] / P2[axis, axis]
    other = P2[1 - axis, 3] / P2[1 - axis, 1 - axis]
    direction = "horizontal" if axis == 0 else "vertical"
    if abs(other) > _RELATIVE * abs(given) or abs(abs(given) - np.linalg.norm(T)) > _RELATIVE * np.linalg.norm(T):
        raise ValueError(f"P2 does not hold the {direction} baseline of T ({np.linalg.norm(T):g} mm along "
                         f"{'x' if axis == 0 else 'y'} after rectification; P2 gives {P2[0, 3] / P2[0, 0]:g}, "
                         f"{P2[1, 3] / P2[1, 1]:g})")
    expected = {(0, 3): -P1[0, 2], (1, 3): -P1[1, 2], (2, 3): P1[0, 0], (3, 2): -1.0 / given}
    for (i, j), value in expected.items():
        if not abs(Q[i, j] - value) <= _RELATIVE * max(abs(value), 1e-9):
            raise ValueError(f"Q does not follow from P1 and P2 (Q[{i},{j}] is {Q[i, j]:g}, expected {value:g})")
