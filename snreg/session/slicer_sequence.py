"""The probe pose stream of a session as a sequence for 3D Slicer: ``snreg session export S.h5 --format
slicer-sequence -o DIR`` writes ``DIR/ProbeTipToTrocar.seq.mha``.

The poses: the stored probe stream holds the tip and axis in the camera frame per fix, not the IMU orientation,
so the stored IMU samples are fused again with the live filter, the orientation is interpolated (slerp) at each
fix's host time, and each fix is mapped through the session's chain at the camera's insertion at that time
(:mod:`.pose_streams`: the tracked insertion of ``streams/camera``, the chain's constant distance when the
session has none): ``trocar_from_probe`` per fix, mm, the tip at the probe frame's origin and z along the probe
from the tip backwards, as the live link's ``ProbeTipToTrocar``. Not RAS: in Slicer the sequence goes under the
``TrocarToRas`` transform of a registration. The live acquisition interpolated the orientation at the frame's grab
time from the live filter; the filter run again from the first stored sample agrees with it once it has settled.

The format, checked against Slicer's documentation and source: Slicer's ``.seq.nrrd`` is a *volume* sequence (3
spatial axes and a list axis); a sequence of linear transforms is stored by Slicer's
``vtkMRMLLinearTransformSequenceStorageNode`` (its default extension ``.seq.mha``) in PLUS's sequence metafile:
a MetaIO header with no image (``DimSize = 0 0 N``), then per frame ``Seq_Frame<k>_<Name>Transform = `` the 16
numbers row by row, ``Seq_Frame<k>_<Name>TransformStatus = OK`` and ``Seq_Frame<k>_Timestamp = `` seconds, and
``ElementDataFile = LOCAL`` last. Slicer names the sequence ``<Name>`` (here ``ProbeTipToTrocar``), uses the
timestamps rounded to milliseconds as its index values and reads lines of up to 1000 characters. The header
written here is the one Slicer writes, plus ``BinaryDataByteOrderMSB = False``, which PLUS's description requires.

The file is written under a temporary name and renamed, so a reader never sees half a file.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from snreg.chain import camera_from_probe, trocar_from_probe
from snreg.session import Session, SessionError
from snreg.session.reader import readable_rows
from snreg.session.pose_streams import insertions_at, orientations_at

__all__ = ["ProbePoses", "probe_poses", "write_slicer_sequence", "SEQUENCE_NAME"]

SEQUENCE_NAME = "ProbeTipToTrocar"          # the live link's device name, so replay and live look alike in Slicer


@dataclass(frozen=True, eq=False)
class ProbePoses:
    """Every stored fix: host time (N,) ns and ``trocar_from_probe`` (N, 4, 4) mm; ``imu``: how the orientation was
    got; ``insertion_mm`` (N,): the camera's insertion each fix was mapped with."""

    t_host_ns: np.ndarray
    trocar_from_probe: np.ndarray
    imu: str
    insertion_mm: np.ndarray | None = None


def probe_poses(path: str | Path) -> ProbePoses:
    """The probe pose stream of the session at ``path`` in the trocar frame; :class:`SessionError` in one sentence."""
    with Session.open(path) as session:
        chain = session.calibration().get("chain")
        probe, imu, camera = (_rows(session.stream(name)) for name in ("probe", "imu", "camera"))
    if chain is None:
        raise SessionError(f"{path}: the session has no chain calibration, so its probe fixes cannot be put in the "
                           "trocar frame; record with a calibrated rig")
    if len(probe) == 0:
        raise SessionError(f"{path}: the session holds no probe fixes to export")
    t_ns = np.asarray(probe["t_host_ns"], dtype=np.int64)
    orientations, source = orientations_at(imu, t_ns)
    insertions = insertions_at(camera, t_ns, chain.trocar_camera_mm)
    chains = {d: chain.with_insertion(d) for d in np.unique(insertions)}
    poses = np.stack([trocar_from_probe(chains[insertions[k]], orientations[k],
                                        camera_from_probe(probe["tip_mm"][k], probe["axis"][k]))
                      for k in range(len(t_ns))])
    return ProbePoses(t_ns, poses, source, insertions)


def write_slicer_sequence(path: str | Path, out_dir: str | Path) -> Path:
    """Write ``ProbeTipToTrocar.seq.mha`` into ``out_dir`` (created if missing); returns its path."""
    poses = probe_poses(path)
    out_dir = Path(out_dir)
    out_dir.mkdir(exist_ok=True)
    target = out_dir / f"{SEQUENCE_NAME}.seq.mha"
    _write_atomically(target, _metafile_bytes(poses))
    return target


def seconds_text(t_ns: int) -> str:
    """A host time in ns as exact decimal seconds (no float rounding)."""
    t_ns = int(t_ns)
    sign, t_ns = ("-", -t_ns) if t_ns < 0 else ("", t_ns)
    return f"{sign}{t_ns // 10**9}.{t_ns % 10**9:09d}"


def _metafile_bytes(poses: ProbePoses) -> bytes:
    lines = ["ObjectType = Image", "NDims = 3", "AnatomicalOrientation = RAI", "BinaryData = True",
             "BinaryDataByteOrderMSB = False", "CompressedData = False", f"DimSize = 0 0 {len(poses.t_host_ns)}",
             "ElementSpacing = 1 1 1", "Offset = 0 0 0", "TransformMatrix = 1 0 0 0 1 0 0 0 1", "ElementType = MET_UCHAR",
             "Kinds = domain domain list"]
    for k, (t_ns, pose) in enumerate(zip(poses.t_host_ns, poses.trocar_from_probe)):
        frame = f"Seq_Frame{k:04d}_"
        lines += [f"{frame}{SEQUENCE_NAME}Transform = " + " ".join(f"{v:.10g}" for v in pose.reshape(-1)),
                  f"{frame}{SEQUENCE_NAME}TransformStatus = OK", f"{frame}Timestamp = {seconds_text(t_ns)}"]
    lines.append("ElementDataFile = LOCAL")
    return ("\n".join(lines) + "\n").encode("ascii")


def _write_atomically(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as out:
            out.write(data)
            out.flush()
            os.fsync(out.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _rows(stream) -> np.ndarray:
    return readable_rows(stream) if isinstance(stream, h5py.Dataset) else np.asarray(stream)
