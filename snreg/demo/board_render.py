"""Synthetic stereo views of a checkerboard, for tests with known ground truth.

The board (frame of :mod:`snreg.calibration.checkerboard`: origin at inner corner 0, x along a
row, y across rows, z into the board, mm) lies on a white sheet with one square of margin and is
seen by both cameras of a :class:`StereoCalibration` against a mid-grey background. Each camera
maps the board plane by the homography ``K [r1 r2 t]`` of its ``camera_from_board``; the right
camera's is ``[R|T] @ camera_from_board`` (OpenCV: ``p_right = R p_left + T``). Lens distortion is
not rendered (the thesis calibration has none). Pixels are supersampled 4 x 4 so edges carry no
aliasing bias; optional Gaussian blur and sensor noise follow under a seed.
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from snreg.calibration.checkerboard import Board
from snreg.camera import StereoCalibration

__all__ = ["render_stereo_board", "random_board_poses", "right_from_left"]

_SUPERSAMPLE = 4
_TEXTURE_PX_PER_MM = 16.0
_DARK, _LIGHT, _BACKGROUND = 30, 225, 110


def right_from_left(calib: StereoCalibration) -> np.ndarray:
    """(4, 4) transform from the left to the right camera frame, mm (``[R|T]`` of the calibration)."""
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = calib.R, np.ravel(calib.T)
    return out


def render_stereo_board(calib: StereoCalibration, board: Board, camera_from_board: np.ndarray, *,
                        noise_sigma: float = 0.0, blur_sigma: float = 0.0, seed: int = 0,
                        bgr: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Left and right uint8 images (H, W), or (H, W, 3) with ``bgr``, of the board at a pose.

    ``camera_from_board`` (4, 4) is the board pose in the LEFT camera frame, mm. ``noise_sigma``
    (grey levels) and ``blur_sigma`` (pixels) add sensor noise and defocus; the noise of both
    images comes from ``seed``.
    """
    camera_from_board = np.asarray(camera_from_board, dtype=float)
    rng = np.random.default_rng(seed)
    images = []
    for K, pose in ((calib.K1, camera_from_board), (calib.K2, right_from_left(calib) @ camera_from_board)):
        image = _render_view(np.asarray(K, dtype=float), pose, board, calib.image_size)
        if blur_sigma > 0:
            image = cv2.GaussianBlur(image, (0, 0), blur_sigma)
        if noise_sigma > 0:
            image = image + rng.normal(0.0, noise_sigma, image.shape)
        image = np.clip(np.rint(image), 0, 255).astype(np.uint8)
        images.append(cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if bgr else image)
    return images[0], images[1]


def random_board_poses(calib: StereoCalibration, board: Board, n: int, seed: int, *,
                       max_tilt_deg: float = 30.0, distance_mm: tuple[float, float] = (150.0, 400.0),
                       max_tries: int = 10000) -> list[np.ndarray]:
    """``n`` varied (4, 4) ``camera_from_board`` poses, each with the whole sheet inside both images.

    The board centre is put on the ray through a uniformly drawn pixel at a uniform distance in
    ``distance_mm``, tilted up to ``max_tilt_deg`` about two in-plane axes and turned freely about
    its normal; draws whose sheet leaves either image are rejected.
    """
    rng = np.random.default_rng(seed)
    width, height = calib.image_size
    K_inv = np.linalg.inv(calib.K1)
    centre = np.array([(board.cols - 1) / 2.0, (board.rows - 1) / 2.0, 0.0]) * board.square_mm
    poses = []
    for _ in range(max_tries):
        if len(poses) == n:
            return poses
        pixel = np.array([rng.uniform(0, width), rng.uniform(0, height), 1.0])
        distance = rng.uniform(*distance_mm)
        tilt_x, tilt_y = rng.uniform(-max_tilt_deg, max_tilt_deg, 2)
        turn = rng.uniform(-180.0, 180.0)
        rotation = Rotation.from_euler("ZXY", [turn, tilt_x, tilt_y], degrees=True).as_matrix()
        ray = K_inv @ pixel
        pose = np.eye(4)
        pose[:3, :3] = rotation
        pose[:3, 3] = ray / np.linalg.norm(ray) * distance - rotation @ centre
        if _sheet_visible(calib, board, pose):
            poses.append(pose)
    if len(poses) == n:
        return poses
    raise ValueError(f"found only {len(poses)} of {n} board poses inside both images; widen the distance range")


def _sheet_corners(board: Board) -> np.ndarray:
    """(4, 3) corners of the white sheet in board coordinates, mm."""
    lo = -2.0 * board.square_mm
    hi_x, hi_y = (board.cols + 1) * board.square_mm, (board.rows + 1) * board.square_mm
    return np.array([[lo, lo, 0.0], [hi_x, lo, 0.0], [hi_x, hi_y, 0.0], [lo, hi_y, 0.0]])


def _sheet_visible(calib: StereoCalibration, board: Board, camera_from_board: np.ndarray, margin_px: float = 4.0) -> bool:
    corners = np.c_[_sheet_corners(board), np.ones(4)].T
    width, height = calib.image_size
    for K, pose in ((calib.K1, camera_from_board), (calib.K2, right_from_left(calib) @ camera_from_board)):
        in_camera = (pose @ corners)[:3]
        if np.any(in_camera[2] <= 1.0):
            return False
        pixels = (K @ in_camera)[:2] / in_camera[2]
        if np.any(pixels < margin_px) or np.any(pixels[0] > width - 1 - margin_px) or np.any(pixels[1] > height - 1 - margin_px):
            return False
    return True


@lru_cache(maxsize=8)
def _texture(board: Board) -> np.ndarray:
    """The sheet as a float32 image at ``_TEXTURE_PX_PER_MM``; pixel centres sampled analytically."""
    lo, hi = _sheet_corners(board)[0], _sheet_corners(board)[2]
    n_x, n_y = (int(round((hi[i] - lo[i]) * _TEXTURE_PX_PER_MM)) for i in (0, 1))
    x = lo[0] + (np.arange(n_x) + 0.5) / _TEXTURE_PX_PER_MM
    y = lo[1] + (np.arange(n_y) + 0.5) / _TEXTURE_PX_PER_MM
    i, j = np.floor(x / board.square_mm).astype(int), np.floor(y / board.square_mm).astype(int)
    inside_x, inside_y = (i >= -1) & (i <= board.cols - 1), (j >= -1) & (j <= board.rows - 1)
    dark = ((np.add.outer(j, i) % 2) == 0) & np.outer(inside_y, inside_x)
    return np.where(dark, _DARK, _LIGHT).astype(np.float32)


def _render_view(K: np.ndarray, camera_from_board: np.ndarray, board: Board, image_size: tuple[int, int]) -> np.ndarray:
    """One float32 (H, W) view: the sheet texture warped by its homography at 4 x 4 supersampling."""
    s = _SUPERSAMPLE
    lo = _sheet_corners(board)[0]
    board_from_texture = np.array([[1 / _TEXTURE_PX_PER_MM, 0, lo[0] + 0.5 / _TEXTURE_PX_PER_MM],
                                   [0, 1 / _TEXTURE_PX_PER_MM, lo[1] + 0.5 / _TEXTURE_PX_PER_MM],
                                   [0, 0, 1]])
    image_from_board = K @ camera_from_board[:3][:, [0, 1, 3]]
    fine_from_image = np.array([[s, 0, (s - 1) / 2.0], [0, s, (s - 1) / 2.0], [0, 0, 1]])
    H = fine_from_image @ image_from_board @ board_from_texture
    width, height = image_size
    fine = cv2.warpPerspective(_texture(board), H, (width * s, height * s), flags=cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_CONSTANT, borderValue=float(_BACKGROUND))
    return cv2.resize(fine, (width, height), interpolation=cv2.INTER_AREA)
