"""Synthetic SPECT written as real NM DICOM: the thesis phantom (§3.2) and blobs of any node set.

Sources are points blurred by a Gaussian of the scanner's resolution (~12 mm FWHM), sampled at
voxel centres, scaled to counts and drawn as Poisson noise from a seeded generator. Files carry
full geometry (LPS) and a pseudonymous patient ("SYNTH-001"); no real person appears.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pydicom.dataset import Dataset, FileMetaDataset
from pydicom.sequence import Sequence
from pydicom.uid import ExplicitVRLittleEndian, generate_uid

from snreg.files import atomic_write

__all__ = ["THESIS_SHAPE", "THESIS_VOXEL_MM", "THESIS_SOURCES", "spect_of_nodes", "write_nm"]

THESIS_SHAPE = (76, 128, 128)        # (slices, rows, columns), thesis §3.2
THESIS_VOXEL_MM = 4.795
# The phantom's four sources (thesis Fig. 14): right external and internal iliac, left external and common iliac.
THESIS_SOURCES = np.array([[-55.0, 20.0, 30.0], [-45.0, 75.0, 45.0], [55.0, 20.0, 30.0], [30.0, 70.0, 110.0]])
NM_IMAGE_STORAGE = "1.2.840.10008.5.1.4.1.1.20"


def spect_of_nodes(xyz, *, activity=None, shape=THESIS_SHAPE, voxel_mm: float = THESIS_VOXEL_MM,
                   centre=(0.0, 50.0, 55.0), fwhm_mm: float = 12.0, peak_counts: float = 2000.0,
                   background: float = 2.0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Noisy counts (Z, Y, X) float32 of point sources at ``xyz`` (N, 3) LPS mm and its (3,) origin mm.

    The volume is axial (identity orientation), ``voxel_mm`` cubic, centred on ``centre`` (mm);
    ``activity`` (N,) scales each source (default 1). The origin is the first voxel's centre.
    """
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    activity = np.ones(len(xyz)) if activity is None else np.asarray(activity, float)
    origin = np.asarray(centre, float) - (np.array(shape[::-1]) - 1) / 2 * voxel_mm
    axes = [origin[a] + voxel_mm * np.arange(shape[2 - a]) for a in range(3)]   # x, y, z sample positions
    sigma = fwhm_mm / (2 * np.sqrt(2 * np.log(2)))
    mean = np.full(shape, background, dtype=float)
    for point, weight in zip(xyz, activity):
        gx, gy, gz = (np.exp(-((axes[a] - point[a]) ** 2) / (2 * sigma**2)) for a in range(3))
        mean += peak_counts * weight * gz[:, None, None] * gy[None, :, None] * gx[None, None, :]
    counts = np.random.default_rng(seed).poisson(mean).astype(np.float32)
    return counts, origin


def write_nm(counts, origin, voxel_mm, path, *, multiframe: bool = True, patient_id: str = "SYNTH-001",
             patient_name: str = "SYNTHETIC^PHANTOM", birth_date: str = "", rescale_slope: float = 1.0,
             patient_position: str | None = "HFS") -> list[Path]:
    """Write counts (Z, Y, X) as NM DICOM; returns the files written.

    ``multiframe``: one reconstructed-tomo file at ``path`` with geometry in the
    DetectorInformationSequence; otherwise one file per slice in directory ``path``
    with ImagePositionPatient per slice. Stored values are counts / ``rescale_slope`` (uint16).
    ``patient_position``: DICOM Patient Position (0018,5100), how the patient lay (None: not written).
    """
    counts = np.asarray(counts, float)
    stored = np.clip(np.round(counts / rescale_slope), 0, 65535).astype(np.uint16)
    spacing = [float(v) for v in np.broadcast_to(voxel_mm, 3)]
    study, series, frame_of_ref = generate_uid(), generate_uid(), generate_uid()
    iop = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    path = Path(path)

    def dataset(pixels: np.ndarray, position, instance: int) -> Dataset:
        ds = _base(patient_id, patient_name, birth_date, study, series, frame_of_ref, instance)
        if patient_position is not None:
            ds.PatientPosition = patient_position
        ds.Rows, ds.Columns = pixels.shape[-2:]
        ds.PixelSpacing = [spacing[1], spacing[0]]
        ds.SliceThickness = spacing[2]
        ds.SpacingBetweenSlices = spacing[2]
        ds.RescaleSlope, ds.RescaleIntercept = rescale_slope, 0.0
        ds.PixelData = pixels.tobytes()
        if pixels.ndim == 3:
            ds.NumberOfFrames = len(pixels)
            ds.NumberOfSlices = len(pixels)
            ds.FrameIncrementPointer = 0x00540080
            ds.SliceVector = list(range(1, len(pixels) + 1))
            detector = Dataset()
            detector.ImagePositionPatient = [float(v) for v in position]
            detector.ImageOrientationPatient = iop
            ds.DetectorInformationSequence = Sequence([detector])
        else:
            ds.ImagePositionPatient = [float(v) for v in position]
            ds.ImageOrientationPatient = iop
        return ds

    if multiframe:
        with atomic_write(path) as temporary:
            dataset(stored, origin, 1).save_as(temporary, enforce_file_format=True)
        return [path]
    path.mkdir(parents=True, exist_ok=True)
    files = []
    for k, plane in enumerate(stored):
        position = np.asarray(origin, float) + [0.0, 0.0, k * spacing[2]]
        files.append(path / f"slice{k + 1:03d}.dcm")
        with atomic_write(files[-1]) as temporary:
            dataset(plane, position, k + 1).save_as(temporary, enforce_file_format=True)
    return files


def _base(patient_id, patient_name, birth_date, study, series, frame_of_ref, instance) -> Dataset:
    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = NM_IMAGE_STORAGE
    meta.MediaStorageSOPInstanceUID = generate_uid()
    meta.TransferSyntaxUID = ExplicitVRLittleEndian
    ds = Dataset()
    ds.file_meta = meta
    ds.SOPClassUID, ds.SOPInstanceUID = NM_IMAGE_STORAGE, meta.MediaStorageSOPInstanceUID
    ds.Modality = "NM"
    ds.ImageType = ["DERIVED", "PRIMARY", "RECON TOMO", "EMISSION"]
    ds.PatientName, ds.PatientID, ds.PatientBirthDate = patient_name, patient_id, birth_date
    ds.StudyInstanceUID, ds.SeriesInstanceUID, ds.FrameOfReferenceUID = study, series, frame_of_ref
    ds.InstanceNumber = instance
    ds.SeriesDescription = "snreg synthetic SPECT"
    ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, "MONOCHROME2"
    ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 16, 15, 0
    return ds
