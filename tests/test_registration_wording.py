"""One wording and rounding rule for a registration (issue 35, items 6 and 10): confidence cut, never rounded up; what
was used said in every output; leave-one-out beside a right pair's; plain words for the internal terms."""

import json
from pathlib import Path

import numpy as np
import pytest

from snreg import geometry
from snreg.cli import main
from snreg.nodes import NodeSet
from snreg.registration import CONFIDENT, register
from snreg.registration.landmark_report import landmark_notes
from snreg.registration.report import pair_expected_mm
from snreg.registration.wording import (CHECK_WORDS, UsedInputs, check_words, confidence_text, confidence_value,
                                        loo_text, rule_words, used_inputs)


@pytest.mark.parametrize("value, text", [(0.947, "0.94"), (0.9499, "0.94"), (0.95, "0.95"), (0.999, "0.99"),
                                         (0.99999, "0.99"), (1.0, "1.00"), (0.0, "0.00")])
def test_a_confidence_reads_on_its_own_side_of_the_threshold_and_one_only_when_certain(value, text):
    assert confidence_text(value) == text
    assert (float(text) >= CONFIDENT) == (value >= CONFIDENT)
    assert (text == "1.00") == (value == 1.0)


@pytest.mark.parametrize("value, cut", [(0.94999, 0.9499), (0.95, 0.95), (0.99996, 0.9999), (1.0, 1.0)])
def test_json_and_csv_values_are_cut_too(value, cut):
    assert confidence_value(value) == cut
    assert (confidence_value(value) >= CONFIDENT) == (value >= CONFIDENT)
    assert confidence_text(value, 4) == f"{cut:.4f}"


def test_a_doubtful_claim_says_what_to_check():
    assert check_words(0.947) == f"({CHECK_WORDS})" and "confirm this node's label or store it again" in CHECK_WORDS
    assert check_words(0.95) == "" and check_words(1.0) == ""


def test_used_inputs_name_what_was_used_and_why_not_the_rest():
    everything = UsedInputs(True, 3, True, True, landmarks_suspect=1)
    assert everything.text() == ("used: labels (left/right, station), 3 landmark pairs, 1 left out as suspect, each "
                                 "stored node's and each hot spot's own error (covariance)")
    nothing = UsedInputs(False, 0, False, False, labels_why="none given", landmarks_why="none given",
                         cov_why="--no-covariances")
    assert nothing.text() == ("used: the positions alone; not used: labels (none given), landmarks (none given), the "
                              "nodes' own errors (covariances: --no-covariances)")
    half = UsedInputs(False, 0, True, False, cov_why="the preop nodes have none")
    assert "used: each stored node's own error (covariance)" in half.text()
    assert "the hot spots' covariances (the preop nodes have none)" in half.text()
    assert half.as_json()["intraop_covariances"] is True and half.as_json()["words"] == half.text()


def _case(offset_mm: float = 0.0):
    """Six pelvic nodes seen through a known transform with 1 mm noise (seed 3), node 3 displaced by ``offset_mm``."""
    xyz = np.array([[-55.0, 20.0, 30.0], [-45.0, 42.0, 8.0], [-47.0, 78.0, 50.0],
                    [52.0, 18.0, 35.0], [44.0, 45.0, 12.0], [12.0, 100.0, 72.0]])
    truth = geometry.make_transform(geometry.rotation_from_euler(10, -5, 8), [10.0, 20.0, 120.0])
    intraop = geometry.apply(truth, xyz) + np.random.default_rng(3).normal(0, 1.0, xyz.shape)
    intraop[2] += [offset_mm, 0.0, offset_mm / 2]
    return xyz, intraop, truth


def test_a_displaced_nodes_leave_one_out_stands_beyond_its_bound_and_the_right_ones_do_not():
    xyz, intraop, truth = _case(12.0)
    result = register(xyz, intraop, initial=truth)
    assert list(result.pairing) == list(range(6))
    nodes = NodeSet.from_xyz(intraop, prefix="SN")
    typical, bound = pair_expected_mm(nodes, result, 0.5), pair_expected_mm(nodes, result)
    assert np.all(typical < bound)
    shown = [loo_text(loo, t, b) for loo, t, b in zip(result.leave_one_out_mm, typical, bound)]
    assert [k for k, text in enumerate(shown) if text.endswith("SUSPECT")] == [2]
    assert shown[0].startswith(f"{result.leave_one_out_mm[0]:.1f} (right: ~{typical[0]:.0f}, <= {bound[0]:.0f})")
    assert loo_text(float("nan"), 3.0, 5.0) == ""


def _files(tmp_path, labels=("EXT R", "OBT R", "INT R", "EXT L", "OBT L", "SAC L")):
    xyz, intraop, truth = _case()
    (tmp_path / "p.csv").write_text(NodeSet.from_xyz(xyz, list(labels), prefix="P").to_csv())
    (tmp_path / "i.csv").write_text(NodeSet.from_xyz(intraop, list(labels), prefix="SN").to_csv())
    np.savetxt(tmp_path / "t.txt", truth)
    return [str(tmp_path / "p.csv"), str(tmp_path / "i.csv"), "--initial", str(tmp_path / "t.txt")]


def test_register_says_what_it_used_in_plain_words_and_cuts_its_confidences(tmp_path, capsys):
    files = _files(tmp_path)
    assert main(["register", *files]) == 0
    out = capsys.readouterr().out
    assert "not used: labels (not asked for: add --labels to forbid left/right crossings)" in out
    assert f"pairing: {rule_words('hot_spot')}" in out and "pairing rule" not in out and "hot_spot" not in out
    assert "(right: ~" in out and "90 % bound" in out and "a large value flags" not in out
    assert main(["register", *files, "--labels"]) == 0
    assert "used: labels (left/right, station)" in capsys.readouterr().out
    assert main(["register", *files, "--labels", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["used"]["labels"] is True and doc["used"]["landmark_pairs"] == 0
    assert doc["used"]["intraop_covariances"] is False and "covariances" in doc["used"]["words"]
    for node in doc["nodes"]:
        assert node["leave_one_out_typical_mm"] < node["leave_one_out_bound_mm"]
    assert main(["register", *files, "--labels"]) == 0
    rows = capsys.readouterr().out.splitlines()
    for node in doc["nodes"]:                            # the table's digits: the JSON's, cut to two places
        row = next(line for line in rows if line.startswith(f"{node['id']} -> "))
        assert row.split()[-1] == confidence_text(node["confidence"])


def test_register_without_labels_on_the_files_says_none_were_given(tmp_path, capsys):
    files = _files(tmp_path, labels=[""] * 6)
    assert main(["register", *files, "--labels"]) == 0
    out = capsys.readouterr().out
    assert "labels (the preop nodes carry none; the intraop nodes carry none)" in out.split("not used:")[1]


def test_a_stored_landmark_without_ct_landmarks_says_none_are_loaded_and_how_to_load_them():
    xyz, intraop, truth = _case()
    result = used = register(xyz, intraop, initial=truth)
    notes = landmark_notes(result, [], ["aortic bifurcation"])
    assert notes == ["landmark 'aortic bifurcation' stored in surgery but no CT landmarks are loaded: load the CT's "
                     "landmarks (a 3D Slicer point list, or a node file's landmark rows) with the preop nodes to use "
                     "them"]
    assert "check its name" in landmark_notes(result, ["left iliac"], ["aortic bifurcation"])[-1]
    assert used_inputs(used, labels=False, intraop_cov=False, preop_cov=False).landmark_pairs == 0


def test_the_demos_text_says_what_it_used_how_to_repeat_it_and_cuts_its_confidences(tmp_path, capsys, monkeypatch):
    """The demo's printed output (its run replaced by a registration of the seeded case, labels typed, one claim made
    doubtful): the used line, the snreg register options that repeat it, confidences cut, what to check."""
    import snreg.demo.headless as headless

    xyz, intraop, truth = _case()
    labels = ["EXT R", "OBT R", "INT R", "EXT L", "OBT L", "SAC L"]
    result = register(xyz, intraop, initial=truth, preop_labels=labels, intraop_labels=labels)
    result.confidence = np.array([0.947, 0.9499, 0.95, 0.999, 0.99999, 1.0])

    def fake_run(path, **_):
        return headless.HeadlessResult(Path(path), Path(path).with_suffix(".dcm"), result, [f"SN{k + 1}" for k in
                                       range(6)], labels, intraop, [f"P{k + 1}" for k in range(6)], True, 10, intraop)

    monkeypatch.setattr(headless, "run_headless", fake_run)
    assert main(["demo", "--headless", "-o", str(tmp_path / "d.h5")]) == 0
    out = capsys.readouterr().out
    shown = [line.split("confidence ")[1].split()[0] for line in out.splitlines() if "confidence " in line]
    assert shown == ["0.94", "0.94", "0.95", "0.99", "0.99", "1.00"]
    assert out.count(f"({CHECK_WORDS})") == 2
    assert "used: labels (left/right, station)" in out and "the stored and SPECT nodes do not all carry one" in out
    assert f"(the same registration again: snreg register {tmp_path / 'd.h5'} --labels)" in out
