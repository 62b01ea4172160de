"""SPECT (NM) and CT DICOM into a :class:`Volume`: voxels in real units plus patient geometry.

Accepts one multi-frame file, a directory of one series, or a list of slice files.
Geometry is the DICOM patient frame (LPS, mm): x to the patient's left, y posterior,
z superior. Where a file carries no geometry (older reconstructed NM, such as the
public ``NM-MONO2-16-13x-heart.dcm`` sample) the volume is placed with identity
orientation at the origin, and :attr:`Volume.placed_by_default` and a warning say so:
node positions are then only meaningful relative to each other.
"""

from __future__ import annotations

import struct
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pydicom
from pydicom.errors import InvalidDicomError
from pydicom.multival import MultiValue

from snreg.errors import PreopError
from snreg.files import require_regular_file

__all__ = ["Volume", "PreopError", "load_volume"]

_PROJECTION_TYPES = {"STATIC", "WHOLE BODY", "DYNAMIC", "GATED", "TOMO", "GATED TOMO"}


@dataclass(frozen=True)
class Volume:
    """voxels (Z, Y, X) float32 in real units (counts, Bq/ml or HU) and its patient geometry.

    ``patient_from_index`` (4, 4) maps a homogeneous index ``(column, row, slice, 1)`` --
    the reverse of the array's axis order -- to LPS patient mm. ``patient_position``: how the patient lay, DICOM
    Patient Position (0018,5100) as written (``"HFS"``, ...; "" when absent), what :mod:`snreg.preop.gravity` turns
    into the down.
    """

    voxels: np.ndarray
    patient_from_index: np.ndarray
    modality: str
    placed_by_default: bool = False
    warnings: tuple[str, ...] = ()
    patient_position: str = ""

    @property
    def spacing_mm(self) -> np.ndarray:
        """(3,) voxel size along column, row and slice index, mm."""
        return np.linalg.norm(self.patient_from_index[:3, :3], axis=0)

    def patient_xyz(self, index_zyx) -> np.ndarray:
        """(N, 3) LPS mm of (N, 3) fractional array indices in (slice, row, column) order."""
        index = np.asarray(index_zyx, dtype=float).reshape(-1, 3)[:, ::-1]
        return index @ self.patient_from_index[:3, :3].T + self.patient_from_index[:3, 3]


def load_volume(path, *, modality: str | None = None) -> Volume:
    """The volume in ``path``: a multi-frame file, a directory of one series, or a list of files.

    ``modality`` (e.g. ``"NM"``) rejects files of another modality. Raises :class:`PreopError`; pydicom's own
    warnings about a file's oddities stay off the terminal (what matters is checked and said here).
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return _load(path, modality)


def _load(path, modality: str | None) -> Volume:
    datasets = _read_all(path)
    found = {str(ds.get("Modality", "")) for ds in datasets}
    if modality and found != {modality}:
        raise PreopError(f"{_name(path)}: modality {'/'.join(sorted(found)) or 'unknown'}, not {modality}; "
                         f"give the {modality} series")
    series = {str(ds.get("SeriesInstanceUID", "")) for ds in datasets}
    if len(series) > 1:
        raise PreopError(f"{_name(path)}: {len(series)} series found; give the files of one series")
    volume = _from_multiframe(datasets[0], _name(path)) if len(datasets) == 1 else _from_slices(datasets, _name(path))
    return replace(volume, patient_position=str(datasets[0].get("PatientPosition", "") or "").strip().upper())


def _name(path) -> str:
    if isinstance(path, (list, tuple)):
        return f"the {len(path)} files given" if len(path) != 1 else str(path[0])
    return str(path)


def _read_all(path) -> list:
    if isinstance(path, (list, tuple)):
        files, skip_non_dicom = [Path(p) for p in path], False
    else:
        path = Path(path)
        if not path.exists():
            raise PreopError(f"{path} does not exist")
        skip_non_dicom = path.is_dir()
        files = sorted(p for p in path.iterdir() if p.is_file()) if skip_non_dicom else [path]
    datasets = []
    for file in files:
        if not skip_non_dicom:
            require_regular_file(file, "DICOM", PreopError)
        try:
            datasets.append(pydicom.dcmread(file))
        except (InvalidDicomError, OSError, ValueError, EOFError, TypeError, KeyError, AttributeError, IndexError,
                OverflowError, NotImplementedError, struct.error):      # what pydicom raises on a damaged file
            if not skip_non_dicom:
                raise PreopError(f"{file} is not a readable DICOM file") from None
    if not datasets:
        raise PreopError(f"no DICOM file found in {_name(path)}")
    return datasets


def _pixels(ds, source: str) -> np.ndarray:
    """Stored values as float32 (frames, rows, columns); undecodable data is a PreopError."""
    if "PixelData" not in ds:
        raise PreopError(f"{source} has no pixel data")
    try:
        raw = ds.pixel_array
    except Exception:  # pydicom raises RuntimeError, NotImplementedError or ValueError per plugin
        syntax = ds.file_meta.get("TransferSyntaxUID")
        if syntax is None or not syntax.is_compressed:
            expected = (int(ds.get("Rows", 0)) * int(ds.get("Columns", 0)) * int(ds.get("NumberOfFrames", 1) or 1)
                        * int(ds.get("SamplesPerPixel", 1)) * int(ds.get("BitsAllocated", 16)) // 8)
            if len(ds.PixelData) < expected:
                raise PreopError(f"{source}: the uncompressed pixel data is incomplete ({len(ds.PixelData)} of "
                                 f"{expected} bytes; the file is probably truncated); copy or export it again") from None
            raise PreopError(f"{source}: the pixel data ({len(ds.PixelData)} bytes) does not match what Rows, Columns, "
                             f"NumberOfFrames, SamplesPerPixel and BitsAllocated say ({expected} bytes); the file's "
                             "header is broken") from None
        raise PreopError(f"{source}: the pixel data ({syntax.name}) cannot be decoded by the installed decoders; "
                         "export it uncompressed") from None
    if ds.get("SamplesPerPixel", 1) != 1:
        raise PreopError(f"{source} is a colour image, not a SPECT or CT volume")
    return np.asarray(raw, dtype=np.float32).reshape(-1, ds.Rows, ds.Columns)


def _real_units(ds, stored: np.ndarray, source: str = "the file") -> np.ndarray:
    """Stored values to real units: a simple linear RealWorldValueMapping for NM, else Rescale."""
    names = ("RescaleSlope", "RescaleIntercept")
    slope, intercept = ds.get("RescaleSlope", 1) or 1, ds.get("RescaleIntercept", 0) or 0
    mapping = ds.get("RealWorldValueMappingSequence")
    if ds.get("Modality") == "NM" and mapping and "RealWorldValueSlope" in mapping[0]:
        names = ("RealWorldValueSlope", "RealWorldValueIntercept")
        slope, intercept = mapping[0].RealWorldValueSlope, mapping[0].get("RealWorldValueIntercept", 0)
    slope, intercept = (float(_numbers(v, 1, name, source)[0]) for v, name in zip((slope, intercept), names))
    with np.errstate(over="ignore", invalid="ignore"):
        voxels = (stored * np.float32(slope) + np.float32(intercept)).astype(np.float32)
    if not np.all(np.isfinite(voxels)):
        raise PreopError(f"{source}: {names[0]} {slope:g} and {names[1]} {intercept:g} take the values beyond what a "
                         "volume can hold; the file's header is broken")
    return voxels


MAX_PATIENT_MM = 1e5           # 100 m from the scanner's origin: anything beyond is a broken header
MAX_VOXEL_MM = 1000.0
MIN_VOXEL_MM = 1e-3            # a micrometre: no SPECT or CT voxel is smaller
_UNIT_TOLERANCE = 1e-3         # DICOM writes direction cosines to a few decimals


def _numbers(value, count: int, name: str, source: str) -> np.ndarray:
    """``count`` finite numbers from a DICOM multi-value, else a PreopError naming the attribute."""
    items = list(value) if isinstance(value, (list, tuple, MultiValue)) else [value]
    try:
        values = np.array([float(v) for v in items], dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise PreopError(f"{source}: {name} holds something that is not a number") from None
    if values.size != count:
        raise PreopError(f"{source}: {name} has {values.size} value(s), not {count}")
    if not np.all(np.isfinite(values)):
        raise PreopError(f"{source}: {name} holds NaN or infinite values")
    return values


def _orientation(iop, source: str) -> np.ndarray:
    """ImageOrientationPatient as two unit, perpendicular direction cosines (6,)."""
    values = _numbers(iop, 6, "ImageOrientationPatient", source)
    row, column = values[:3], values[3:]
    if abs(np.linalg.norm(row) - 1) > _UNIT_TOLERANCE or abs(np.linalg.norm(column) - 1) > _UNIT_TOLERANCE:
        raise PreopError(f"{source}: ImageOrientationPatient is not two unit vectors (lengths "
                         f"{np.linalg.norm(row):.3g} and {np.linalg.norm(column):.3g}); the file's geometry is broken")
    if abs(float(np.dot(row, column))) > _UNIT_TOLERANCE:
        raise PreopError(f"{source}: ImageOrientationPatient gives rows and columns that are not perpendicular "
                         f"(cosine {float(np.dot(row, column)):.3g}); the file's geometry is broken")
    return values


def _pixel_spacing(spacing, source: str) -> np.ndarray:
    """PixelSpacing (row, column) mm: two positive finite numbers."""
    values = _numbers(spacing, 2, "PixelSpacing", source)
    if not np.all((values >= MIN_VOXEL_MM) & (values <= MAX_VOXEL_MM)):
        raise PreopError(f"{source}: PixelSpacing {values[0]:g}, {values[1]:g} mm is not a voxel size (each must lie "
                         f"from {MIN_VOXEL_MM:g} to {MAX_VOXEL_MM:g} mm)")
    return values


def _position(ipp, source: str) -> np.ndarray:
    values = _numbers(ipp, 3, "ImagePositionPatient", source)
    if np.abs(values).max() > MAX_PATIENT_MM:
        raise PreopError(f"{source}: ImagePositionPatient lies {np.abs(values).max():.3g} mm from the origin; the "
                         "file's geometry is broken")
    return values


def _affine(iop, ipp, pixel_spacing, slice_vector) -> np.ndarray:
    row_dir, col_dir = np.asarray(iop[:3], float), np.asarray(iop[3:], float)
    affine = np.eye(4)
    affine[:3, 0] = row_dir * float(pixel_spacing[1])   # along a row: column index, column spacing
    affine[:3, 1] = col_dir * float(pixel_spacing[0])   # down a column: row index, row spacing
    affine[:3, 2] = slice_vector
    affine[:3, 3] = np.asarray(ipp, float)
    return affine


def _slice_spacing(ds, name: str = "the file") -> float | None:
    for source in (ds, _shared_item(ds, "PixelMeasuresSequence")):
        if source is None:
            continue
        for key in ("SpacingBetweenSlices", "SliceThickness"):
            if source.get(key):
                step = abs(float(_numbers(source.get(key), 1, key, name)[0]))
                if not MIN_VOXEL_MM <= step <= MAX_VOXEL_MM:
                    raise PreopError(f"{name}: {key} {step:g} mm is not a slice spacing (it must lie from "
                                     f"{MIN_VOXEL_MM:g} to {MAX_VOXEL_MM:g} mm)")
                return step
    return None


def _shared_item(ds, sequence: str):
    shared = ds.get("SharedFunctionalGroupsSequence")
    if shared and sequence in shared[0]:
        return shared[0].get(sequence)[0]
    return None


def _from_multiframe(ds, source: str) -> Volume:
    stored = _pixels(ds, source)
    image_type = [str(v).upper() for v in ds.get("ImageType", [])]
    if ds.get("Modality") == "NM" and len(image_type) > 2 and image_type[2] in _PROJECTION_TYPES:
        raise PreopError(f"{source} holds NM {image_type[2].lower()} images, not a reconstructed SPECT volume")
    if len(stored) < 2:
        raise PreopError(f"{source} is a single 2D image, not a volume")
    voxels = _real_units(ds, stored, source)
    spacing = ds.get("PixelSpacing") or getattr(_shared_item(ds, "PixelMeasuresSequence"), "PixelSpacing", None)
    iop, ipp = ds.get("ImageOrientationPatient"), ds.get("ImagePositionPatient")
    detector = ds.get("DetectorInformationSequence")
    if (iop is None or ipp is None) and detector and "ImageOrientationPatient" in detector[0]:
        iop, ipp = detector[0].ImageOrientationPatient, detector[0].get("ImagePositionPatient")
    orientation = _shared_item(ds, "PlaneOrientationSequence")
    per_frame = ds.get("PerFrameFunctionalGroupsSequence")
    spacing = None if spacing is None else _pixel_spacing(spacing, source)
    if iop is None and orientation is not None and per_frame:
        iop = _orientation(orientation.ImageOrientationPatient, source)
        positions = [_position(f.PlanePositionSequence[0].ImagePositionPatient, source) for f in per_frame]
        return _volume(voxels, iop, positions, spacing, None, ds, source)
    slice_step = _slice_spacing(ds, source)
    if iop is None or ipp is None or spacing is None or slice_step is None:
        return _default_placement(voxels, spacing, slice_step, ds, source)
    iop, ipp = _orientation(iop, source), _position(ipp, source)
    normal = np.cross(iop[:3], iop[3:])
    return Volume(voxels, _affine(iop, ipp, spacing, normal * slice_step), str(ds.Modality))


def _from_slices(datasets, source: str) -> Volume:
    first = datasets[0]
    iop, spacing = first.get("ImageOrientationPatient"), first.get("PixelSpacing")
    if iop is None or spacing is None or any("ImagePositionPatient" not in ds for ds in datasets):
        raise PreopError(f"{source}: the slices lack ImagePositionPatient/ImageOrientationPatient/PixelSpacing, "
                         "so they cannot be stacked in order")
    iop, spacing = _orientation(iop, source), _pixel_spacing(spacing, source)
    normal = np.cross(iop[:3], iop[3:])
    where = {id(ds): _position(ds.ImagePositionPatient, source) for ds in datasets}
    datasets = sorted(datasets, key=lambda ds: float(np.dot(normal, where[id(ds)])))
    stored = np.concatenate([_real_units(ds, _pixels(ds, source), source) for ds in datasets])
    positions = [where[id(ds)] for ds in datasets]
    return _volume(stored, iop, positions, spacing, normal, first, source)


def _volume(voxels, iop, positions, spacing, normal, ds, source: str) -> Volume:
    """A volume whose slice vector comes from the positions of consecutive slices (mm)."""
    positions = np.asarray(positions, float)
    if spacing is None:
        raise PreopError(f"{source} has no PixelSpacing, so its voxel size is unknown")
    if len(positions) != len(voxels) or len(positions) < 2:
        raise PreopError(f"{source}: {len(positions)} slice positions for {len(voxels)} slices")
    steps = np.diff(positions, axis=0)
    step = (positions[-1] - positions[0]) / (len(positions) - 1)
    if np.linalg.norm(step) < 1e-6 or np.max(np.linalg.norm(steps - step, axis=1)) > 0.01 * np.linalg.norm(step) + 1e-3:
        raise PreopError(f"{source}: the slices are not evenly spaced (missing or repeated slices?)")
    return Volume(voxels, _affine(iop, positions[0], spacing, step), str(ds.get("Modality", "")))


def _default_placement(voxels, spacing, slice_step, ds, source: str) -> Volume:
    pixel = [float(v) for v in spacing] if spacing is not None else [1.0, 1.0]
    step = slice_step or 1.0
    affine = np.diag([pixel[1], pixel[0], step, 1.0])
    warning = (f"{source} carries no patient position/orientation; the volume is placed with identity "
               f"orientation at the origin ({pixel[1]:g} x {pixel[0]:g} x {step:g} mm voxels"
               f"{'' if spacing is not None and slice_step else ', some sizes assumed 1 mm'}), so node positions are "
               "relative to the volume corner, not to the patient")
    return Volume(voxels, affine, str(ds.get("Modality", "")), placed_by_default=True, warnings=(warning,))
