"""snreg.preop.volume: NM/CT DICOM (multi-frame, series) into voxels plus LPS geometry."""

from pathlib import Path

import numpy as np
import pydicom
import pytest
from pydicom.dataset import Dataset
from pydicom.sequence import Sequence

from snreg.demo.spect import write_nm
from snreg.preop import PreopError, load_volume

DICOM_DIR = Path(__file__).resolve().parent / "data" / "dicom"
HEART = DICOM_DIR / "NM-MONO2-16-13x-heart.dcm"
JPEG = DICOM_DIR / "NM1_JPLY.dcm"
VOXEL = (4.0, 3.5, 5.0)          # x, y, z mm: distinct so that axis mix-ups show
ORIGIN = np.array([-30.0, -20.0, 10.0])


@pytest.fixture
def counts():
    return np.random.default_rng(7).integers(0, 500, size=(6, 5, 4)).astype(np.float32)   # (Z, Y, X)


def test_multiframe_voxels_and_geometry(tmp_path, counts):
    write_nm(counts, ORIGIN, VOXEL, tmp_path / "nm.dcm", rescale_slope=0.5)
    volume = load_volume(tmp_path / "nm.dcm")
    assert volume.voxels.shape == (6, 5, 4) and volume.voxels.dtype == np.float32
    np.testing.assert_allclose(volume.voxels, np.round(counts / 0.5) * 0.5)   # RescaleSlope applied
    np.testing.assert_allclose(volume.spacing_mm, VOXEL)
    np.testing.assert_allclose(volume.patient_xyz([[0, 0, 0], [5, 4, 3]]), [ORIGIN, ORIGIN + [12.0, 14.0, 25.0]])
    assert volume.modality == "NM" and not volume.placed_by_default and volume.warnings == ()


def test_series_directory_and_shuffled_file_list_match_the_multiframe_file(tmp_path, counts):
    write_nm(counts, ORIGIN, VOXEL, tmp_path / "nm.dcm")
    files = write_nm(counts, ORIGIN, VOXEL, tmp_path / "series", multiframe=False)
    reference = load_volume(tmp_path / "nm.dcm")
    for source in (tmp_path / "series", [files[k] for k in np.random.default_rng(1).permutation(len(files))]):
        volume = load_volume(source)
        np.testing.assert_array_equal(volume.voxels, reference.voxels)
        np.testing.assert_allclose(volume.patient_from_index, reference.patient_from_index, atol=1e-9)


def test_orientation_from_the_detector_information_maps_indices_to_patient_mm(tmp_path, counts):
    path = write_nm(counts, ORIGIN, VOXEL, tmp_path / "nm.dcm")[0]
    ds = pydicom.dcmread(path)
    ds.DetectorInformationSequence[0].ImageOrientationPatient = [-1, 0, 0, 0, -1, 0]   # rows run to the right
    ds.save_as(path)
    volume = load_volume(path)
    np.testing.assert_allclose(volume.patient_xyz([[2, 1, 3]]), [ORIGIN + [-12.0, -3.5, 10.0]])   # normal (-x) x (-y) = +z


def test_per_frame_functional_groups_give_the_slice_positions(tmp_path, counts):
    path = write_nm(counts, ORIGIN, VOXEL, tmp_path / "nm.dcm")[0]
    ds = pydicom.dcmread(path)
    del ds.DetectorInformationSequence
    orientation, shared, frames = Dataset(), Dataset(), []
    orientation.ImageOrientationPatient = [1, 0, 0, 0, 1, 0]
    shared.PlaneOrientationSequence = Sequence([orientation])
    ds.SharedFunctionalGroupsSequence = Sequence([shared])
    for k in range(len(counts)):
        position, frame = Dataset(), Dataset()
        position.ImagePositionPatient = list(ORIGIN + [0.0, 0.0, -7.0 * k])   # feet-first, 7 mm apart
        frame.PlanePositionSequence = Sequence([position])
        frames.append(frame)
    ds.PerFrameFunctionalGroupsSequence = Sequence(frames)
    ds.save_as(path)
    volume = load_volume(path)
    np.testing.assert_allclose(volume.patient_from_index[:3, 2], [0.0, 0.0, -7.0])
    np.testing.assert_allclose(volume.patient_from_index[:3, 3], ORIGIN)


def test_real_world_value_mapping_gives_nm_units(tmp_path, counts):
    path = write_nm(counts, ORIGIN, VOXEL, tmp_path / "nm.dcm")[0]
    ds = pydicom.dcmread(path)
    mapping = Dataset()
    mapping.RealWorldValueSlope, mapping.RealWorldValueIntercept = 2.5, 1.0
    ds.RealWorldValueMappingSequence = Sequence([mapping])
    ds.save_as(path)
    np.testing.assert_allclose(load_volume(path).voxels, counts * 2.5 + 1.0)


def test_ct_series_in_hounsfield_units(tmp_path, counts):
    files = write_nm(counts, ORIGIN, VOXEL, tmp_path / "ct", multiframe=False)
    for file in files:
        ds = pydicom.dcmread(file)
        ds.Modality, ds.RescaleIntercept = "CT", -1024.0
        ds.save_as(file)
    volume = load_volume(tmp_path / "ct", modality="CT")
    assert volume.modality == "CT"
    np.testing.assert_allclose(volume.voxels, counts - 1024.0)


def test_real_nm_heart_sample_is_placed_by_default_with_a_warning():
    volume = load_volume(HEART, modality="NM")
    assert volume.voxels.shape == (13, 64, 64)
    np.testing.assert_allclose(volume.spacing_mm, [3.11583, 3.11583, 6.231669], rtol=1e-5)
    assert volume.placed_by_default
    np.testing.assert_allclose(volume.patient_from_index[:3, 3], 0.0)
    assert "no patient position/orientation" in volume.warnings[0] and "origin" in volume.warnings[0]


def test_lossy_jpeg_sample_gives_a_clear_error():
    with pytest.raises(PreopError, match="cannot be decoded.*export it uncompressed"):
        load_volume(JPEG)


def test_not_dicom(tmp_path):
    (tmp_path / "notes.txt").write_text("not an image")
    with pytest.raises(PreopError, match="not a readable DICOM file"):
        load_volume(tmp_path / "notes.txt")
    with pytest.raises(PreopError, match="no DICOM file found in"):
        load_volume(tmp_path)
    with pytest.raises(PreopError, match="does not exist"):
        load_volume(tmp_path / "missing.dcm")


def test_wrong_modality(tmp_path, counts):
    write_nm(counts, ORIGIN, VOXEL, tmp_path / "nm.dcm")
    with pytest.raises(PreopError, match="modality NM, not CT"):
        load_volume(tmp_path / "nm.dcm", modality="CT")


def test_a_series_with_a_missing_slice_is_refused(tmp_path, counts):
    files = write_nm(counts, ORIGIN, VOXEL, tmp_path / "series", multiframe=False)
    files[2].unlink()
    with pytest.raises(PreopError, match="not evenly spaced"):
        load_volume(tmp_path / "series")


def test_a_series_without_positions_is_refused(tmp_path, counts):
    files = write_nm(counts, ORIGIN, VOXEL, tmp_path / "series", multiframe=False)
    ds = pydicom.dcmread(files[1])
    del ds.ImagePositionPatient
    ds.save_as(files[1])
    with pytest.raises(PreopError, match="cannot be stacked"):
        load_volume(tmp_path / "series")


def test_a_single_image_and_planar_nm_are_not_volumes(tmp_path, counts):
    files = write_nm(counts, ORIGIN, VOXEL, tmp_path / "series", multiframe=False)
    with pytest.raises(PreopError, match="single 2D image"):
        load_volume(files[0])
    path = write_nm(counts, ORIGIN, VOXEL, tmp_path / "nm.dcm")[0]
    ds = pydicom.dcmread(path)
    ds.ImageType = ["ORIGINAL", "PRIMARY", "WHOLE BODY", "EMISSION"]
    ds.save_as(path)
    with pytest.raises(PreopError, match="not a reconstructed SPECT volume"):
        load_volume(path)
