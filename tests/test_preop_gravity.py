"""Down in the preop frame (issue 30): from the SPECT's Patient Position turned head down by the table's tilt, refused in
words when the position gives none, kept with the nodes in a node CSV's comments."""

from pathlib import Path

import numpy as np
import pytest

from snreg.cli.preop import MAX_TILT_DEG as CLI_MAX_TILT, TABLE_TILT_DEG as CLI_TILT
from snreg.cli.register import MAX_TILT_DEG as REGISTER_MAX_TILT
from snreg.demo.spect import THESIS_VOXEL_MM, spect_of_nodes, write_nm
from snreg.errors import PreopError
from snreg.preop.gravity import MAX_TILT_DEG, TABLE_TILT_DEG, PreopDown, check_tilt, volume_down
from snreg.preop.volume import load_volume

HEART = Path(__file__).resolve().parent / "data" / "dicom" / "NM-MONO2-16-13x-heart.dcm"


@pytest.mark.parametrize("position, level", [("HFS", [0, 1, 0]), ("FFS", [0, 1, 0]), ("HFP", [0, -1, 0]),
                                             ("FFP", [0, -1, 0]), (" hfs ", [0, 1, 0])])
def test_supine_is_posterior_prone_anterior_on_a_level_table(position, level):
    np.testing.assert_allclose(PreopDown(position, 0.0).vector, level, atol=1e-12)


@pytest.mark.parametrize("position", ["HFS", "FFP"])
def test_a_head_down_tilt_gives_the_down_a_superior_component(position):
    level = PreopDown(position, 0.0).vector
    for tilt in (10.0, 30.0, 60.0):
        down = PreopDown(position, tilt).vector
        assert np.linalg.norm(down) == pytest.approx(1.0)
        assert down[2] == pytest.approx(np.sin(np.radians(tilt)))             # the head goes down: +z (superior)
        assert np.degrees(np.arccos(down @ level)) == pytest.approx(tilt)      # turned about the left-right axis
        assert down[0] == 0.0


def test_the_default_tilt_is_30_degrees_and_the_command_line_agrees():
    assert TABLE_TILT_DEG == CLI_TILT == 30.0 and MAX_TILT_DEG == CLI_MAX_TILT == REGISTER_MAX_TILT == 60.0
    down = PreopDown("HFS")
    assert not down.tilt_entered and down.source == "DICOM HFS (supine, head first), table tilt 30 deg head down (default)"
    assert down.with_tilt(25).source.endswith("table tilt 25 deg head down (entered)")


@pytest.mark.parametrize("position, words", [
    ("", "no usable patient position"), ("HFDR", "on their side (Patient Position HFDR)"),
    ("FFDL", "on their side"), ("HFDL", "on their side"), ("FFDR", "on their side"),
    ("LFS", "'LFS' is none of HFS, FFS, HFP, FFP")])
def test_a_position_without_a_down_says_why_in_one_sentence(position, words):
    down = PreopDown(position)
    assert words in down.problem
    with pytest.raises(PreopError, match=words.split("(")[0].strip()) as caught:
        down.vector
    assert "\n" not in str(caught.value)


@pytest.mark.parametrize("tilt", [-1.0, 60.5, float("nan"), float("inf"), "steep"])
def test_a_tilt_outside_0_to_60_degrees_is_refused(tilt):
    with pytest.raises(PreopError, match="0 to 60 degrees head down"):
        PreopDown("HFS", tilt)
    with pytest.raises(PreopError, match="0 to 60 degrees"):
        check_tilt(tilt)


def test_comments_keep_the_position_and_tilt_and_files_from_elsewhere_have_none():
    for down in (PreopDown("HFP", 22.5, True), PreopDown(""), PreopDown("HFDR", 0.0)):
        kept = PreopDown.from_comments(["frame note", *down.comments()])
        assert kept == down
        assert PreopDown.from_json(down.to_json()) == down
    assert PreopDown("").comments()[0] == "patient_position: none"
    assert PreopDown.from_comments(["placed by default: ..."]) is None
    assert PreopDown.from_comments(["patient_position: FFS"]) == PreopDown("FFS")          # tilt absent: the default
    with pytest.raises(PreopError, match="p.csv: the comment 'table_tilt_deg: 75 \\(entered\\)'"):
        PreopDown.from_comments(["patient_position: HFS", "table_tilt_deg: 75 (entered)"], "p.csv")


def _spect(tmp_path, **kwargs):
    xyz = np.array([[10.0, 40.0, 60.0], [-20.0, 60.0, 50.0], [30.0, 70.0, 40.0]])
    counts, origin = spect_of_nodes(xyz, centre=xyz.mean(axis=0), seed=2)
    return load_volume(write_nm(counts, origin, THESIS_VOXEL_MM, tmp_path / "s.dcm", **kwargs)[0])


def test_the_volume_gives_its_patient_position_and_the_operator_the_tilt(tmp_path):
    volume = _spect(tmp_path)
    assert volume.patient_position == "HFS"
    assert volume_down(volume) == PreopDown("HFS", 30.0, False)
    assert volume_down(volume, 12.0) == PreopDown("HFS", 12.0, True)
    assert _spect(tmp_path, patient_position=None).patient_position == ""
    assert "no usable patient position" in volume_down(_spect(tmp_path, patient_position=None)).problem
    assert "on their side" in volume_down(_spect(tmp_path, patient_position="FFDR")).problem


def test_a_real_spect_without_patient_geometry_gives_no_down():
    """The public NM heart sample carries neither Patient Position nor an image orientation (placed by default)."""
    volume = load_volume(HEART)
    assert volume.placed_by_default
    assert "no usable patient position" in volume_down(volume).problem
