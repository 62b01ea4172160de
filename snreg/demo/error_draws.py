"""The phantom experiment under an error model: its geometry, one seeded draw of every source's error, and the node
sets a registration then sees (``compose``).

Why: the error budget (``snreg budget``) and the realistic demo (``snreg demo --errors``) must err alike. The
geometry is the demo phantom's (:mod:`snreg.demo.scene`, :mod:`snreg.demo.phantom`): four nodes at 85-118 mm from
the camera (thesis §5.2.1: a typical operating distance of 100 mm), stored left nodes first, then, after the camera
turned about the vertical towards them (thesis §5.1: it was moved between the left and the right nodes), the right
ones; the endoscope looks down 34 degrees below the horizontal (the demo's set-up), so a yaw error of the IMU swings
the view sideways. Each node's truth is where the probe tip is rendered (camera frame) carried through the true chain
at its pose; its SPECT source is that point before the tissue shifted, in patient coordinates of the true set-up.

A draw holds each source's error as the code measured it or the formula drew it; ``compose`` scales each source by
the model's factor (0 off) and carries everything through :mod:`snreg.chain` as the app does, so sources interact as
they would (an IMU error only moves nodes seen at another orientation; a camera turn costs nothing by itself).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from snreg.chain import THESIS_IMU_TROCAR_MM, THESIS_TROCAR_CAMERA_MM, ChainCalibration, camera_to_trocar, trocar_from_camera
from snreg.demo.error_stages import imu_session_errors
from snreg.demo.errors import ErrorModel
from snreg.demo.imu_simulator import SensorModel
from snreg.demo.phantom import NOMINAL_TILT_DEG, PHANTOM_LABELS, setup_patient_from_trocar
from snreg.demo.scene import PROBE_AXIS, phantom_tips
from snreg.geometry import apply, invert
from snreg.probe import ProbeModel

__all__ = ["PhantomGeometry", "ErrorDraw", "Scenario", "phantom_geometry", "draw_errors", "compose",
           "camera_displacements", "fused_imu_errors", "cohort_geometry", "ENDOSCOPE_TILT_DEG"]

ENDOSCOPE_TILT_DEG = 34.0          # the demo set-up's endoscope below the horizontal (snreg.demo.phantom)


@dataclass(frozen=True, eq=False)
class PhantomGeometry:
    """The phantom: probe tips (N, 3) and axis (3,) in the camera frame of each node's store, each node's pose (0 left,
    1 right: after the camera turn), the store order, labels, and the IMU's orientation at pose 0."""

    tips_camera: np.ndarray
    axis_camera: np.ndarray
    poses: np.ndarray
    store_order: tuple[int, ...]
    labels: tuple[str, ...]
    earth_from_imu: Rotation

    @property
    def n(self) -> int:
        return len(self.tips_camera)


def phantom_geometry(probe: ProbeModel) -> PhantomGeometry:
    """The demo phantom (:func:`~snreg.demo.scene.phantom_tips`), left nodes stored first, looking down 34 degrees."""
    labels = tuple(PHANTOM_LABELS)
    poses = np.array([1 if label.endswith("R") else 0 for label in labels])
    order = tuple(int(k) for k in np.argsort(poses, kind="stable"))
    # the shaft (camera z = IMU z, axes aligned) points ENDOSCOPE_TILT_DEG below the horizontal, heading 0
    earth_from_imu = Rotation.from_euler("y", 90.0 + ENDOSCOPE_TILT_DEG, degrees=True)
    return PhantomGeometry(phantom_tips(probe), PROBE_AXIS.copy(), poses, order, labels, earth_from_imu)


def cohort_geometry(nodes_lps: np.ndarray, labels, phantom: PhantomGeometry, turn_deg: float) -> PhantomGeometry:
    """A patient's nodes (N, 3) LPS mm with their labels as the phantom experiment would meet them: turned into the
    trocar frame by the nominal set-up with their centroid where the phantom's nodes are, stored left first (side from
    the label, else from x: LPS +x is the patient's left), each seen from its side's pose (the camera turned
    ``turn_deg`` for the right side) as the phantom's are."""
    nodes = np.asarray(nodes_lps, float)
    sides = [str(label).strip()[-1:] if str(label).strip()[-1:] in ("L", "R") else ("L" if x > nodes[:, 0].mean()
             else "R") for label, x in zip(labels, nodes[:, 0])]
    poses = np.array([1 if side == "R" else 0 for side in sides])
    reference = ChainCalibration.manual().with_reference(phantom.earth_from_imu)
    at_pose = [trocar_from_camera(reference, phantom.earth_from_imu)]
    turned = Rotation.from_euler("z", turn_deg, degrees=True) * phantom.earth_from_imu   # the right side's pose
    at_pose.append(trocar_from_camera(reference, turned))
    centre = np.mean([apply(at_pose[p], t[None])[0] for p, t in zip(phantom.poses, phantom.tips_camera)], axis=0)
    trocar_from_patient = invert(setup_patient_from_trocar(NOMINAL_TILT_DEG))
    trocar = apply(trocar_from_patient, nodes) - apply(trocar_from_patient, nodes.mean(axis=0)[None])[0] + centre
    tips = np.array([apply(invert(at_pose[p]), t[None])[0] for p, t in zip(poses, trocar)])
    order = tuple(int(k) for k in np.argsort(poses, kind="stable"))
    return PhantomGeometry(tips, phantom.axis_camera, poses, order, tuple(str(v) for v in labels), phantom.earth_from_imu)


def fused_imu_errors(model: ErrorModel, geometry: PhantomGeometry, seed: int) -> np.ndarray | None:
    """(N, 3) rotation vectors of the fused orientation's error at each node's store, from one simulated session of
    the model's sensor through the fusion (:func:`~snreg.demo.error_stages.imu_session_errors`); None when the
    model's IMU is off or perfect."""
    imu = model.values["imu"]
    if not model.on("imu") or not (imu["gyro_bias_dps"] or imu["gyro_noise_dps"] or imu["accel_noise_g"]):
        return None
    sensor = SensorModel(accel_noise_density_g=imu["accel_noise_g"], gyro_noise_density_dps=imu["gyro_noise_dps"],
                         gyro_bias_max_dps=imu["gyro_bias_dps"])
    order = list(geometry.store_order)
    errors = imu_session_errors(earth_from_imu_start=geometry.earth_from_imu, turn_deg=model["camera", "turn_deg"],
                                store_poses=[int(geometry.poses[k]) for k in order], interval_s=imu["node_interval_s"],
                                sensor=sensor, fusion=str(imu["fusion"]), seed=seed)
    by_node = np.zeros((geometry.n, 3))
    by_node[order] = errors
    return by_node


@dataclass(frozen=True, eq=False)
class ErrorDraw:
    """One draw of every source's error; camera-frame vectors (N, 3) mm unless said.

    calibration: tracked with the estimated calibration minus tracked with the true one, on the same frames;
    tracking: tracked with the true calibration minus truth; residual: the tracker error the renderer does not make;
    pointing: probe tip minus node; imu: (N, 3) rotation vectors (earth frame) of the fused orientation's error;
    turn_error_deg: signed error of the measured camera turn; chain: IMU-trocar and trocar-camera distance errors (mm)
    and the IMU-camera misalignment (rotation vector); insertion (2,): change of the camera's distance from the pivot
    per pose, mm; insertion_tracked (2,): the insertion tracker's error per pose, mm (used when it is tracked); tissue: (N, 3) shift between scan and surgery (trocar frame); spect: (N, 3) segmented
    centre minus source (patient LPS).
    """

    calibration: np.ndarray
    tracking: np.ndarray
    residual: np.ndarray
    pointing: np.ndarray
    imu: np.ndarray
    turn_error_deg: float
    chain_mm: np.ndarray
    misalignment: np.ndarray
    insertion: np.ndarray
    insertion_tracked: np.ndarray
    tissue: np.ndarray
    spect: np.ndarray


def draw_errors(model: ErrorModel, geometry: PhantomGeometry, rng: np.random.Generator, *, calibration=None,
                tracking=None, imu=None, spect=None) -> ErrorDraw:
    """The formula-drawn sources from ``rng``; the code-measured ones (calibration, tracking, imu, spect) as given
    (zeros when None: the caller decides which it measured)."""
    n = geometry.n
    zeros = np.zeros((n, 3))
    p = model.values
    # pointing (formula): the count peak puts the axis anywhere within lateral_mm of the node, the node's centre up
    # to axial_mm ahead of the tip (the tip touches the tissue above it)
    u = geometry.axis_camera
    e1 = np.cross(u, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    radius = p["pointing"]["lateral_mm"] * np.sqrt(rng.uniform(0, 1, n))
    angle = rng.uniform(0, 2 * np.pi, n)
    ahead = rng.uniform(0, p["pointing"]["axial_mm"], n)
    pointing = radius[:, None] * (np.cos(angle)[:, None] * e1 + np.sin(angle)[:, None] * e2) + ahead[:, None] * u
    residual = rng.normal(0.0, p["tracking"]["residual_mm"], (n, 3))
    imu_p = p["imu"]
    turn_error = rng.normal(imu_p["turn_error_deg"], imu_p["turn_error_sd_deg"]) * rng.choice([-1.0, 1.0])
    chain_p = p["chain"]
    chain_mm = rng.normal(0.0, [chain_p["imu_trocar_sd_mm"], chain_p["trocar_camera_sd_mm"]])
    axis = rng.normal(size=3)
    misalignment = np.radians(chain_p["imu_camera_deg"]) * axis / np.linalg.norm(axis)
    insertion = rng.normal(0.0, p["camera"]["insertion_sd_mm"], 2)
    tissue = rng.normal(0.0, p["tissue"]["per_node_mm"], (n, 3))
    insertion_tracked = rng.normal(0.0, p["camera"]["tracked_sd_mm"], 2)
    given = [zeros if v is None else np.asarray(v, float) for v in (calibration, tracking, imu, spect)]
    return ErrorDraw(given[0], given[1], residual, pointing, given[2], float(turn_error), chain_mm, misalignment,
                     insertion, insertion_tracked, tissue, given[3])


@dataclass(frozen=True, eq=False)
class Scenario:
    """What a registration sees and the truth to score it: preop (N, 3) LPS and intraop (N, 3) trocar frame (both
    measured, with their labels), the true nodes in both frames, the true ``trocar_from_patient``, the rotation
    each node's store saw the camera at, and what the rig mapped each node with: its tip (N, 3) in the camera frame,
    the chain (at the insertion it used) and the IMU orientation (N, 3, 3), as measured."""

    preop: np.ndarray
    preop_labels: list[str]
    intraop: np.ndarray
    intraop_labels: list[str]
    sources_lps: np.ndarray
    nodes_trocar: np.ndarray
    trocar_from_patient: np.ndarray
    store_rotation: np.ndarray      # (N, 3, 3) true trocar_from_camera rotation at each node's store
    tips_camera: np.ndarray         # (N, 3) measured tips, camera frame
    chains: tuple                   # (N,) ChainCalibration each node was mapped with
    earth_from_imu: np.ndarray      # (N, 3, 3) measured IMU orientation at each node's store

    @property
    def node_errors(self) -> np.ndarray:
        """(N, 3) what the registration must absorb at each node beyond the true rigid map: the measured intraop
        node minus the measured preop node carried by the true ``trocar_from_patient``."""
        return self.intraop - apply(self.trocar_from_patient, self.preop)


def _pose_rotations(model: ErrorModel, geometry: PhantomGeometry) -> list[Rotation]:
    turn = model.on("camera") * model["camera", "turn_deg"]
    turned = Rotation.from_euler("z", turn, degrees=True) * geometry.earth_from_imu
    return [geometry.earth_from_imu, turned]


def compose(model: ErrorModel, geometry: PhantomGeometry, draw: ErrorDraw) -> Scenario:
    """The node sets under ``model``'s scaled sources (a scale of 0 leaves a source out) for this draw."""
    s = {source: model.on(source) for source in model.scale}
    poses = _pose_rotations(model, geometry)
    reference = ChainCalibration.manual().with_reference(geometry.earth_from_imu).trocar_from_earth

    def chain(imu_trocar_mm: float, trocar_camera_mm: float) -> ChainCalibration:
        base = ChainCalibration.manual(imu_trocar_mm, trocar_camera_mm)
        return ChainCalibration(base.imu_from_camera, base.imu_trocar_mm, reference)

    truth, rotations = [], []
    for k in range(geometry.n):
        pose = int(geometry.poses[k])
        true_chain = chain(THESIS_IMU_TROCAR_MM, THESIS_TROCAR_CAMERA_MM + s["camera"] * draw.insertion[pose])
        truth.append(camera_to_trocar(true_chain, poses[pose], geometry.tips_camera[k]))
        rotations.append(trocar_from_camera(true_chain, poses[pose])[:3, :3])
    nodes_trocar = np.array(truth)
    tilt = NOMINAL_TILT_DEG + s["tissue"] * model["tissue", "setup_tilt_deg"]
    patient_from_trocar = setup_patient_from_trocar(tilt, s["tissue"] * model["tissue", "setup_turn_deg"])
    sources_lps = apply(patient_from_trocar, nodes_trocar - s["tissue"] * draw.tissue)
    preop = sources_lps + s["spect"] * draw.spect
    measured_chain = chain(THESIS_IMU_TROCAR_MM + s["chain"] * draw.chain_mm[0],
                           THESIS_TROCAR_CAMERA_MM + s["chain"] * draw.chain_mm[1])
    if model["camera", "insertion"] == "tracked":       # the tracker measures the change, with its own error
        measured_chains = [measured_chain.with_insertion(measured_chain.trocar_camera_mm + s["camera"] * (
            draw.insertion[pose] + draw.insertion_tracked[pose])) for pose in (0, 1)]
    else:
        measured_chains = [measured_chain, measured_chain]
    misaligned = Rotation.from_rotvec(s["chain"] * draw.misalignment)
    turned = s["camera"] * model["camera", "turn_deg"] > 0
    tips = (geometry.tips_camera + s["pointing"] * draw.pointing + s["tracking"] * (draw.tracking + draw.residual)
            + s["calibration"] * draw.calibration)
    intraop, orientations = [], []
    for k in range(geometry.n):
        pose = int(geometry.poses[k])
        error = Rotation.from_rotvec(s["imu"] * draw.imu[k])
        if turned and pose == 1:
            error = Rotation.from_euler("z", s["imu"] * draw.turn_error_deg, degrees=True) * error
        measured = error * poses[pose] * misaligned
        intraop.append(camera_to_trocar(measured_chains[pose], measured, tips[k]))
        orientations.append(measured.as_matrix())
    # preop labels: the side alone, as the segmentation gives it (the station comes from the radiologist, thesis §3.3)
    return Scenario(preop, [label.strip()[-1:] for label in geometry.labels], np.array(intraop), list(geometry.labels),
                    sources_lps, nodes_trocar, invert(patient_from_trocar), np.array(rotations), tips,
                    tuple(measured_chains[int(pose)] for pose in geometry.poses), np.array(orientations))


def camera_displacements(model: ErrorModel, geometry: PhantomGeometry, draw: ErrorDraw, sources) -> np.ndarray:
    """(N, 3) camera-frame displacements of the stored nodes that ``sources`` cause in this draw (each expressed in
    the camera frame of its node's store): what the demo adds to the rendered probe for the sources its rig cannot
    run through code (a camera that never turns, an IMU held still)."""
    scenario = compose(model.only(sources), geometry, draw)
    offsets = scenario.intraop - scenario.nodes_trocar
    return np.einsum("nji,nj->ni", scenario.store_rotation, offsets)
