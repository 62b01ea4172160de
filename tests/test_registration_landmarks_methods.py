"""Landmark pairs with every method (issue 34): icp, cpd and chamfer fit with them as global does, a wrong pair is a
suspect whichever method fitted, a set too small to check says so, names pair in the core, and the covariance fit
warns before inverting an ill-conditioned Hessian."""

import json
import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from snreg.cli import main
from snreg.landmarks import LANDMARKS
from snreg.nodes import NodeSet, write_nodes
from snreg.registration import METHODS, IllConditionedWarning, register
from snreg.registration._covariance import _check_conditioning
from snreg.registration.landmark_report import landmark_notes

NAMES = LANDMARKS[:3]
MARKS = np.array([[0.0, 85.0, 160.0], [-40.0, 80.0, 95.0], [40.0, 80.0, 95.0]])      # mm, preop frame
TURN = Rotation.from_euler("ZYX", [12.0, -8.0, 5.0], degrees=True).as_matrix()
SHIFT = np.array([6.0, -4.0, 9.0])
NODE_SD_MM, MARK_SD_MM = 5.0, 2.0


def surgery(xyz):
    """Where points of the preop frame truly lie in the intraop frame."""
    return np.asarray(xyz) @ TURN.T + SHIFT


def case(seed: int, wrong_mm: float = 0.0):
    """Seeded pelvic nodes (5, well apart), their stored positions (sd 5 mm per axis), and three landmark pairs (sd
    2 mm per axis), the first moved ``wrong_mm`` along x in surgery."""
    rng = np.random.default_rng(seed)
    while True:
        preop = rng.uniform([-80.0, -60.0, 0.0], [80.0, 30.0, 130.0], (5, 3))
        gaps = np.linalg.norm(preop[:, None] - preop[None], axis=-1) + 1e9 * np.eye(5)
        if gaps.min() >= 25.0:
            break
    intraop = surgery(preop) + rng.normal(0.0, NODE_SD_MM, preop.shape)
    touched = surgery(MARKS) + rng.normal(0.0, MARK_SD_MM, MARKS.shape)
    touched[0, 0] += wrong_mm
    return preop, intraop, dict(zip(NAMES, MARKS)), dict(zip(NAMES, touched))


def node_error_mm(result, preop) -> float:
    """Mean distance between the preop nodes mapped by the result and where they truly are."""
    mapped = preop @ result.transform[:3, :3].T + result.transform[:3, 3]
    return float(np.linalg.norm(mapped - surgery(preop), axis=1).mean())


@pytest.mark.parametrize("method", METHODS)
def test_a_landmark_40_mm_wrong_is_suspect_with_every_method(method):
    for seed in (1, 2):
        preop, intraop, marks, touched = case(seed, wrong_mm=40.0)
        result = register(preop, intraop, method=method, preop_landmarks=marks, intraop_landmarks=touched)
        assert result.landmarks_suspect == [NAMES[0]], (seed, result.landmark_residual_mm)
        assert result.landmark_residual_mm[NAMES[0]] > 30.0
        assert all(result.landmark_residual_mm[name] < 10.0 for name in NAMES[1:])
        assert result.landmarks_checkable


@pytest.mark.slow
@pytest.mark.parametrize("method", METHODS)
def test_right_landmarks_make_no_suspect_and_the_fit_no_worse(method):
    """Over seeded cases, the nodes land closer to the truth with three right landmark pairs than without: the pairs
    enter every method's fit (issue 34: icp, cpd and chamfer used to ignore them)."""
    without, with_marks = [], []
    for seed in range(1, 7):
        preop, intraop, marks, touched = case(seed)
        plain = register(preop, intraop, method=method)
        marked = register(preop, intraop, method=method, preop_landmarks=marks, intraop_landmarks=touched)
        assert marked.landmarks_suspect == [], seed
        without.append(node_error_mm(plain, preop))
        with_marks.append(node_error_mm(marked, preop))
    assert np.mean(with_marks) <= np.mean(without), (with_marks, without)


@pytest.mark.parametrize("method", ["icp", "cpd", "chamfer"])
def test_the_thesis_methods_fit_with_the_landmarks(method):
    """The fit itself moves with the pairs: the same nodes with the landmark pairs land elsewhere than without, the
    right pairs' residuals near their own error."""
    preop, intraop, marks, touched = case(3)
    plain = register(preop, intraop, method=method)
    marked = register(preop, intraop, method=method, preop_landmarks=marks, intraop_landmarks=touched)
    assert np.abs(marked.transform - plain.transform).max() > 0.1
    plain_residual = np.linalg.norm(surgery(MARKS) - (MARKS @ plain.transform[:3, :3].T + plain.transform[:3, 3]),
                                    axis=1).mean()
    assert np.mean(list(marked.landmark_residual_mm.values())) < plain_residual


def small_case():
    """One node and two landmarks (3 points in all), the second landmark touched 30 mm off."""
    preop = np.array([[10.0, 20.0, 30.0]])
    marks = dict(zip(NAMES[:2], MARKS[:2]))
    touched = dict(zip(NAMES[:2], surgery(MARKS[:2]) + [[0.0, 0.0, 0.0], [30.0, 0.0, 0.0]]))
    return preop, surgery(preop), marks, touched


def test_one_node_and_two_landmarks_cannot_be_checked_and_say_so():
    preop, intraop, marks, touched = small_case()
    result = register(preop, intraop, preop_landmarks=marks, intraop_landmarks=touched)
    assert result.landmarks_checkable is False
    assert all(np.isnan(v) for v in result.landmark_leave_one_out_mm.values())
    assert any("3 points in all: a wrong landmark would not show" in text for text in landmark_notes(result))


def test_four_points_can_be_checked():
    preop, intraop, marks, touched = small_case()
    marks[NAMES[2]], touched[NAMES[2]] = MARKS[2], surgery(MARKS[2])
    result = register(preop, intraop, preop_landmarks=marks, intraop_landmarks=touched)
    assert result.landmarks_checkable is True
    assert not any("would not show" in text for text in landmark_notes(result))


def test_without_landmarks_nothing_is_said_about_them():
    preop, intraop, _, _ = case(1)
    result = register(preop, intraop)
    assert result.landmarks_checkable is True and landmark_notes(result) == []


def test_snreg_register_says_why_a_small_set_cannot_be_checked(tmp_path, capsys):
    preop, intraop, marks, touched = small_case()
    write_nodes(NodeSet(["P1"], [""], preop), tmp_path / "preop.csv",
                landmarks=NodeSet(list(marks), ["", ""], np.array(list(marks.values()))))
    write_nodes(NodeSet(["SN1"], [""], intraop), tmp_path / "intraop.csv",
                landmarks=NodeSet(list(touched), ["", ""], np.array(list(touched.values()))))
    args = ["register", str(tmp_path / "preop.csv"), str(tmp_path / "intraop.csv")]
    assert main(args + ["--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["landmarks_checkable"] is False
    assert main(args) == 0
    out = capsys.readouterr().out
    assert ("warning: 3 points in all: a wrong landmark would not show; touch another landmark or store another node "
            "to check them") in out


def test_names_pair_in_the_core_whatever_their_case_and_spaces():
    preop, intraop, marks, touched = case(4)
    spelled = {"  Aortic  Bifurcation ": touched[NAMES[0]], NAMES[1].upper(): touched[NAMES[1]],
               NAMES[2]: touched[NAMES[2]]}
    result = register(preop, intraop, preop_landmarks={"aortic bifurcation": marks[NAMES[0]], NAMES[1]: marks[NAMES[1]],
                                                       NAMES[2]: marks[NAMES[2]]}, intraop_landmarks=spelled)
    assert sorted(result.landmark_residual_mm) == sorted(NAMES)
    assert all(value < 10.0 for value in result.landmark_residual_mm.values())


def test_the_same_name_twice_in_other_spellings_is_refused():
    preop, intraop, marks, touched = case(4)
    with pytest.raises(ValueError, match="given twice"):
        register(preop, intraop, preop_landmarks=marks,
                 intraop_landmarks={"Aortic Bifurcation": touched[NAMES[0]], "aortic  bifurcation": touched[NAMES[0]]})


def test_an_ill_conditioned_covariance_fit_warns_in_words():
    well = np.diag([1e4, 1e4, 1e4, 1.0, 1.0, 1.0])[None]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _check_conditioning(well)                      # mm against radians alone: no warning
    singular = well.copy()
    singular[0, 2, 2] = 1e-9                           # the turn about one axis not determined (collinear pairs)
    with pytest.warns(IllConditionedWarning, match="lie nearly on one line"):
        _check_conditioning(singular)


def test_the_live_links_status_says_a_small_set_cannot_be_checked(igtl_client):
    from snreg.workflow.live_link import LiveLink

    preop, intraop, marks, touched = small_case()
    result = register(preop, intraop, preop_landmarks=marks, intraop_landmarks=touched)
    with LiveLink(0, stall_drop_s=60.0) as link:
        client = igtl_client(link.port)
        link.set_registration(result, "SN1 -> P1")
        link.flush()
        assert client.wait_for(lambda c: any("would not show" in m.string for m in c.messages("Status")))
        [said] = [m.string for m in client.messages("Status") if "would not show" in m.string][-1:]
        assert ("registered with global" in said and "3 points in all: a wrong landmark would not show; touch another "
                "landmark or store another node to check them" in said and said.endswith("SN1 -> P1"))
