"""The demo phantom in the patient: where its four sources lie on the SPECT, their labels, and how the patient and
the endoscope lie on the operating table, and the operator's rough set-up alignment the error budget starts from.

Why: the phantom experiment (thesis §4.2) registers a SPECT of the phantom to the nodes stored with the
probe. The demo needs that SPECT with a known truth: the four sources sit where the rendered probe tip
rests (trocar frame), carried into patient coordinates (LPS mm) by a set-up pose that a real operating room would
only know roughly (:func:`setup_patient_from_trocar`). The registration finds its own start from gravity: the SPECT is
written with the patient supine (``PATIENT_POSITION``), the table is tilted head down (``TABLE_TILT_DEG``, a few
degrees from the 30 the team enters), and the still endoscope's IMU is held as the endoscope lies in that tilted
patient (:func:`endoscope_orientation`), with the chain's reference there (:func:`still_demo_chain`), so the trocar
frame is the camera frame shifted along the shaft, as before.

Set-up geometry: patient supine, the endoscope entering near the umbilicus and looking caudally into the
pelvis, tilted ``tilt_deg`` below the patient's coronal plane (the horizontal of a level table), image "up" anterior,
so the image's right is the patient's right (LPS -x) and the camera's y axis points posteriorly.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from snreg.chain import ChainCalibration, camera_to_trocar
from snreg.demo.spect import spect_of_nodes, write_nm
from snreg.geometry import apply, invert, make_transform

# Labels of the four phantom nodes of snreg.demo.scene: sides from the phantom midline (the tips with camera
# x below the mean lie on the patient's left), stations near (EXT) and far (OBT).
PHANTOM_LABELS = ("EXT L", "EXT R", "OBT R", "OBT L")
TRUE_TILT_DEG, TRUE_TURN_DEG = 34.0, 7.0          # the set-up as it happened
NOMINAL_TILT_DEG = 30.0                           # the set-up as the operator assumes it
TROCAR_LPS_MM = np.array([0.0, -110.0, 210.0])    # the pivot point near the umbilicus
PATIENT_POSITION = "HFS"                          # supine, head first: on the scanner and on the operating table
TABLE_TILT_DEG = 27.0                             # the table's head-down tilt as it happened (the team enters 30)
# the patient on a level table in the IMU's earth frame (x north, y west, z up): head north, posterior down
_EARTH_FROM_LEVEL_LPS = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def setup_patient_from_trocar(tilt_deg: float, turn_deg: float = 0.0, trocar_lps=TROCAR_LPS_MM) -> np.ndarray:
    """(4, 4) ``patient_from_trocar`` (LPS mm) for an endoscope looking caudally, ``tilt_deg`` below horizontal,
    turned ``turn_deg`` towards the patient's left about the anterior-posterior axis."""
    t = np.radians(tilt_deg)
    axes = np.column_stack([[-1.0, 0.0, 0.0], [0.0, np.cos(t), np.sin(t)], [0.0, np.sin(t), -np.cos(t)]])
    turn = Rotation.from_euler("y", turn_deg, degrees=True).as_matrix()
    return make_transform(turn @ axes, trocar_lps)


def earth_from_patient(table_tilt_deg: float = TABLE_TILT_DEG) -> np.ndarray:
    """(3, 3) the supine patient (LPS) in the IMU's earth frame on a table tilted ``table_tilt_deg`` head down: the head
    goes down, so gravity gains a superior component (as :mod:`snreg.preop.gravity` has it for HFS)."""
    return Rotation.from_euler("y", table_tilt_deg, degrees=True).as_matrix() @ _EARTH_FROM_LEVEL_LPS


def endoscope_orientation(setup_deg: tuple[float, float] = (TRUE_TILT_DEG, TRUE_TURN_DEG),
                          table_tilt_deg: float = TABLE_TILT_DEG) -> np.ndarray:
    """(3, 3) ``earth_from_imu`` of the still endoscope (IMU axes the camera's, the camera along the trocar axis) at the
    set-up (tilt, turn) in the patient on the tilted table; headed so the IMU's yaw is 0, as the AHRS starts it (it has
    no compass)."""
    earth_from_camera = earth_from_patient(table_tilt_deg) @ setup_patient_from_trocar(*setup_deg)[:3, :3]
    yaw = Rotation.from_matrix(earth_from_camera).as_euler("ZYX")[0]
    return Rotation.from_euler("z", -yaw).as_matrix() @ earth_from_camera


def still_demo_chain(earth_from_imu: np.ndarray) -> ChainCalibration:
    """The thesis' manual chain with its reference at the still endoscope's orientation (as a trocar calibration there
    would set it): the trocar frame is the camera frame shifted along the shaft, and gravity is seen in it."""
    return ChainCalibration.manual().with_reference(earth_from_imu)


def true_sources_lps(truth_tips_camera: np.ndarray, chain: ChainCalibration, *,
                     setup_deg: tuple[float, float] = (TRUE_TILT_DEG, TRUE_TURN_DEG), scan_shift_mm=0.0,
                     earth_from_imu=None) -> np.ndarray:
    """(4, 3) source positions (LPS mm): the rendered tips carried through the chain at the camera's start orientation
    ``earth_from_imu`` (default: the IMU level) and the true set-up (tilt, turn); ``scan_shift_mm`` (4, 3, trocar
    frame): how far each node moved between the scan and the surgery."""
    orientation = np.eye(3) if earth_from_imu is None else earth_from_imu
    trocar = camera_to_trocar(chain, orientation, truth_tips_camera) - scan_shift_mm
    return apply(setup_patient_from_trocar(*setup_deg), trocar)


def write_phantom_spect(sources_lps: np.ndarray, path: str | Path, seed: int = 0, *, voxel_mm: float = 4.795,
                        **spect) -> Path:
    """The phantom's SPECT (thesis geometry: 128x128x76, 4.795 mm, Poisson counts) as one NM DICOM file; ``spect``:
    :func:`~snreg.demo.spect.spect_of_nodes`' ``fwhm_mm`` and ``peak_counts`` (an error model's)."""
    centre = np.asarray(sources_lps, float).mean(axis=0)
    counts, origin = spect_of_nodes(sources_lps, centre=centre, seed=seed, voxel_mm=voxel_mm, **spect)
    return write_nm(counts, origin, voxel_mm, Path(path), patient_id="PHANTOM-DEMO", patient_name="PHANTOM^DEMO",
                    patient_position=PATIENT_POSITION)[0]


def rough_alignment(preop_lps: np.ndarray, intraop_trocar: np.ndarray) -> np.ndarray:
    """(4, 4) ``intraop_from_preop`` as an operator would set it: the nominal set-up rotation, centroids matched (the
    error budget's start; the demo itself starts from gravity)."""
    rotation = invert(setup_patient_from_trocar(NOMINAL_TILT_DEG))[:3, :3]
    shift = np.mean(intraop_trocar, axis=0) - rotation @ np.mean(preop_lps, axis=0)
    return make_transform(rotation, shift)


def hot_spot_of_sources(preop_xyz, sources) -> np.ndarray:
    """(S,) for each phantom source (S, 3) LPS mm, the index of the segmented hot spot nearest it: the correspondence
    the demo's pairing, its navigation and its SPECT report are judged by."""
    preop_xyz, sources = np.asarray(preop_xyz, float).reshape(-1, 3), np.asarray(sources, float).reshape(-1, 3)
    return np.argmin(np.linalg.norm(sources[:, None, :] - preop_xyz[None, :, :], axis=2), axis=1)


def spect_report(preop_ids, preop_xyz, sources) -> dict[str, str]:
    """The phantom SPECT as a nuclear-medicine physician reports it: each hot spot's station (``{"P1": "EXT"}``), the
    station written on the phantom source it shows (:data:`PHANTOM_LABELS`), as a report names each sentinel node's
    station on the SPECT/CT (thesis Table 1); a ``snreg preop --stations`` table."""
    nearest = hot_spot_of_sources(preop_xyz, sources)
    return {str(preop_ids[k]): PHANTOM_LABELS[n].split()[0] for n, k in enumerate(nearest)}


def write_station_table(path: str | Path, stations: dict[str, str]) -> Path:
    """Write ``stations`` as ``snreg preop --stations`` reads it (CSV ``id,station``)."""
    path = Path(path)
    path.write_text("id,station\n" + "".join(f"{i},{station}\n" for i, station in sorted(stations.items())),
                    encoding="utf-8")
    return path
