import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from snreg import geometry


def rx(a):
    c, s = np.cos(np.radians(a)), np.sin(np.radians(a))
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def ry(a):
    c, s = np.cos(np.radians(a)), np.sin(np.radians(a))
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rz(a):
    c, s = np.cos(np.radians(a)), np.sin(np.radians(a))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def test_euler_is_rz_ry_rx_of_yaw_pitch_roll():
    yaw, pitch, roll = 30.0, -20.0, 10.0
    expected = rz(yaw) @ ry(pitch) @ rx(roll)
    np.testing.assert_allclose(geometry.rotation_from_euler(yaw, pitch, roll), expected, atol=1e-12)


@pytest.mark.parametrize("angles", [(10, 20, 30), (-170, 45, -60), (0, 0, 0), (90, -30, 179)])
def test_euler_round_trip(angles):
    rot = geometry.rotation_from_euler(*angles)
    np.testing.assert_allclose(geometry.euler_from_rotation(rot), angles, atol=1e-9)


def test_rotation_distance_is_thesis_eq5():
    p = geometry.rotation_from_euler(10, 0, 0)
    q = geometry.rotation_from_euler(-15, 0, 0)
    assert geometry.rotation_distance_deg(p, q) == pytest.approx(25.0)
    a = Rotation.random(random_state=3).as_matrix()
    b = Rotation.random(random_state=4).as_matrix()
    expected = np.degrees((Rotation.from_matrix(a) * Rotation.from_matrix(b).inv()).magnitude())
    assert geometry.rotation_distance_deg(a, b) == pytest.approx(expected)


def test_invert_and_apply():
    t = geometry.transform_from_euler(20, 30, -40, [5, -6, 7])
    pts = np.random.default_rng(0).normal(size=(5, 3))
    np.testing.assert_allclose(geometry.apply(geometry.invert(t), geometry.apply(t, pts)), pts, atol=1e-12)
    np.testing.assert_allclose(geometry.invert(t) @ t, np.eye(4), atol=1e-12)


def test_kabsch_recovers_a_transform_single_and_batched():
    rng = np.random.default_rng(1)
    src = rng.normal(size=(3, 6, 3)) * 40
    truth = np.stack([geometry.transform_from_euler(*rng.uniform(-90, 90, 3), rng.uniform(-50, 50, 3)) for _ in range(3)])
    dst = np.stack([geometry.apply(t, s) for t, s in zip(truth, src)])
    np.testing.assert_allclose(geometry.kabsch(src, dst), truth, atol=1e-9)
    np.testing.assert_allclose(geometry.kabsch(src[1], dst[1]), truth[1], atol=1e-9)


def test_kabsch_never_returns_a_reflection():
    src = np.array([[0.0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 10]])
    mirrored = src * np.array([1, 1, -1])
    t = geometry.kabsch(src, mirrored)
    assert np.linalg.det(t[:3, :3]) == pytest.approx(1.0)
