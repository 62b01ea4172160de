"""Store SN, Store landmark and undo over the store window of :class:`~snreg.workflow.acquisition.Acquisition` (the
last valid fixes its pairs gave), and the guard that refuses a store: the half of the acquisition a store request
runs, beside the half each pair runs.

A store is refused, with the reason in words and on record in the session's events (``store_refused``), when the
window is not full, its newest fix is stale (the probe is out of view), the IMU is absent or stale (unless the
acquisition runs without an IMU by choice) or the window spreads over the limit
(:class:`~snreg.workflow.store_guard.StoreLimits`, 2 mm by default); a store within ``duplicate_mm`` of a stored node
needs ``confirmed=True`` (:class:`~snreg.errors.StoreNeedsConfirmation` names that node). Auto-store keeps its stricter
rule (held still within the acquisition's ``STILL_SPREAD_MM``, over :data:`AUTO_STORE_SEPARATION_MM` from every stored
node and landmark) on top of the guard.

Store landmark (issue 29) stores the window as an anatomical landmark (kind ``landmark``, id = its name, provenance as
a node's) under the same guard; a landmark of that name already stored asks first, and confirmed, the new one replaces
it (the old stays on record: journal, ``landmark_replaced`` event). Undo takes back the last stored, node or landmark.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from snreg.errors import StoreError, StoreNeedsConfirmation, StoreRefused
from snreg.landmarks import LANDMARK, NODE, landmark_name
from snreg.session import IntraopNode
from snreg.tracking import summarise
from snreg.tracking.uncertainty import node_covariance_sources, summed_covariance
from snreg.workflow.store_guard import StoreCheck, nearest_node, same_landmark

__all__ = ["NodeStore", "WindowFix", "IMU_ABSENT", "AUTO_STORE_SEPARATION_MM"]

AUTO_STORE_SEPARATION_MM = 10.0  # auto-store only this far from every stored node: one node per rest
IMU_ABSENT = "absent"            # the IMU state of a rig run without one (chosen in the device dialog)


@dataclass(frozen=True, eq=False)
class WindowFix:
    """One valid fix of the store window, as it was mapped."""

    camera: np.ndarray
    axis: np.ndarray       # the probe's axis, camera frame
    trocar: np.ndarray
    quat_xyzw: np.ndarray
    imu_gap_s: float
    imu_state: str
    grabbed_ns: int        # its frame's (left) grab time: the stream rows' clock
    seen_ns: int           # host time it was computed
    insertion_mm: float    # the camera's insertion it was mapped with (NaN: the chain's own, tracking off)
    insertion_sd_mm: float  # that insertion's change's sd since the start (tracked or held; NaN: tracking off)


class NodeStore:
    """Store SN, Store landmark, undo and their guard, mixed into :class:`~snreg.workflow.acquisition.Acquisition`:
    they read its store window (``_fixes``, the last IMU reading and tracker reason, its clock), its session,
    limits, chain, insertion and calibration versions, and keep what this run stored (``_stored_here``,
    ``error_sources``)."""

    def check_store(self, window=None) -> StoreCheck:
        """Whether Store SN would store now, and if not why (in words); the near node when one is. ``window``: the
        store window's summary when the caller has it already."""
        return self._check(window, lambda here: nearest_node(self.session.intraop_records(), here,
                                                             self.limits.duplicate_mm))

    def check_landmark(self, name: str, window=None) -> StoreCheck:
        """Whether Store landmark would store ``name`` now: Store SN's guard, and the landmark of that name when one
        is stored (``near``, to ask about first)."""
        return self._check(window, lambda here: same_landmark(self.session.intraop_records(LANDMARK), name, here))

    def _check(self, window, near: Callable[[np.ndarray], StoreCheck]) -> StoreCheck:
        """The guard's refusal in words, else ``near`` at the window's median (with the insertion's overridable
        refusal when the camera may have moved)."""
        n, needed = len(self._fixes), self.fixes_per_node
        if n < needed:
            return StoreCheck(f"only {n} of {needed} valid fixes so far; hold the probe on the node")
        age_s = (self._clock() - self._fixes[-1].seen_ns) / 1e9
        if age_s > self.limits.fix_stale_s:
            lost = f" ({self._last_reason})" if self._last_reason else ""
            return StoreCheck(f"the last valid fix is {age_s:.1f} s old{lost}: the probe is not tracked now; "
                              "bring it into view and hold it on the node")
        imu_problem = self._imu_problem()
        if imu_problem:
            return StoreCheck(imu_problem)
        window = window or self._window_trocar()
        if window.spread_mm > self.limits.max_spread_mm:
            return StoreCheck(f"the probe moved: the last {needed} fixes spread {window.spread_mm:.1f} mm (limit "
                              f"{self.limits.max_spread_mm:.1f} mm); hold it still on the node")
        found = near(window.xyz)
        moved = self.insertion.store_refusal() if self.insertion is not None else ""
        return replace(found, refusal=moved, overridable=True) if moved else found

    def store(self, node_id: str, label: str, *, counts: float = float("nan"), left_jpeg=b"", right_jpeg=b"",
              confirmed: bool = False, trigger: str = "", override: bool = False) -> IntraopNode:
        """The median of the store window as node ``node_id``, durable on return, with the camera-frame tip, the mean
        IMU orientation, the calibration versions and the median insertion it was mapped with; its time is its newest
        fix's grab time (on the streams' clock: the node points at its own probe rows, however late the store was
        asked). Refused (:class:`StoreRefused`, put on record with ``trigger``, e.g. "F5") as :meth:`check_store`
        says, unless the refusal is overridable and ``override`` is True (the node is stored and a ``store_override``
        event keeps the refusal); :class:`StoreNeedsConfirmation` when a stored node is near and ``confirmed`` is
        False. Snapshots are JPEG bytes or BGR images."""
        return self._store(self.check_store(), str(node_id), label, NODE, counts, left_jpeg, right_jpeg, confirmed,
                           trigger, override)

    def store_landmark(self, name: str, *, left_jpeg=b"", right_jpeg=b"", confirmed: bool = False, trigger: str = "",
                       override: bool = False) -> IntraopNode:
        """The median of the store window as the anatomical landmark ``name`` (kind landmark, id = the name as
        :func:`~snreg.landmarks.landmark_name` keeps it), stored and guarded as :meth:`store` stores a node;
        :class:`StoreError` when the name is missing or not a landmark name; :class:`StoreNeedsConfirmation` when a
        landmark of that name is stored and ``confirmed`` is False; confirmed, this one replaces it."""
        try:
            name = landmark_name(name)
        except ValueError as err:
            raise StoreError(f"{err}; pick one of the preop landmarks or type its name") from None
        return self._store(self.check_landmark(name), name, "", LANDMARK, float("nan"), left_jpeg, right_jpeg,
                           confirmed, trigger, override)

    def _store(self, check: StoreCheck, node_id: str, label: str, kind: str, counts: float, left_jpeg, right_jpeg,
               confirmed: bool, trigger: str, override: bool) -> IntraopNode:
        """Store the window as ``node_id`` of ``kind`` once ``check`` allows it (refusals and confirmations as
        :meth:`store` says; a confirmed landmark replaces the stored one of its name)."""
        overriding = bool(check.refusal) and check.overridable and override
        if check.refusal and not overriding:
            self.session.log_event("store_refused", reason=check.refusal, trigger=str(trigger), node_id=node_id,
                                   **({"overridable": True} if check.overridable else {}),
                                   **({"landmark": True} if kind == LANDMARK else {}))
            raise StoreRefused(check.refusal, overridable=check.overridable)
        if check.near is not None and not confirmed:
            raise StoreNeedsConfirmation(check.question, check.near.id)
        if kind == LANDMARK and check.near is not None:
            self.session.remove_intraop_node(node_id)
            self.session.log_event("landmark_replaced", node_id=node_id, distance_mm=round(check.near_mm, 2),
                                   old_xyz_trocar=[round(float(v), 3) for v in check.near.xyz_trocar],
                                   trigger=str(trigger))
        camera = summarise(np.array([f.camera for f in self._fixes]))
        trocar = summarise(np.array([f.trocar for f in self._fixes]))
        orientation = Rotation.from_quat(np.array([f.quat_xyzw for f in self._fixes])).mean().as_matrix()
        insertion = float(np.median([f.insertion_mm for f in self._fixes]))
        sources = self._covariance_sources(camera.xyz, orientation, insertion)
        node = self.session.add_intraop_node(node_id, label, trocar.xyz, xyz_camera=camera.xyz,
                                             spread_mm=trocar.spread_mm, n_frames=trocar.n_frames, counts=counts,
                                             time_ns=self._fixes[-1].grabbed_ns, left_jpeg=left_jpeg,
                                             right_jpeg=right_jpeg, earth_from_imu=orientation,
                                             stereo_version=self.stereo_version, chain_version=self.chain_version,
                                             trocar_camera_mm=insertion,
                                             cov_trocar_mm2=summed_covariance(sources), kind=kind)
        if overriding:
            self.session.log_event("store_override", node_id=node.id, reason=check.refusal, trigger=str(trigger))
        if check.near is not None and kind == NODE:
            self.session.log_event("store_near_confirmed", node_id=node.id, near=check.near.id,
                                   distance_mm=round(check.near_mm, 2), trigger=str(trigger))
        self._stored_here.append(node.id)
        self.error_sources[node.id] = sources
        return node

    def _covariance_sources(self, tip_camera: np.ndarray, earth_from_imu: np.ndarray, insertion_mm: float) -> dict:
        """The store window's node covariance by source ((3, 3) mm^2 each, trocar frame), at its insertion's chain."""
        axes = np.array([f.axis for f in self._fixes])
        chain = self.chain if not np.isfinite(insertion_mm) else self.chain.with_insertion(insertion_mm)
        slide = np.array([f.insertion_sd_mm for f in self._fixes])
        return node_covariance_sources(self.uncertainty, self.tracker.calibration, self.tracker.probe, chain,
                                       earth_from_imu, tip_camera, axes.mean(axis=0),
                                       window_camera=np.array([f.camera for f in self._fixes]),
                                       insertion_sd_mm=float(np.median(slide)) if np.isfinite(slide).all() else None)

    def undo(self) -> IntraopNode:
        """Take back the node or landmark stored last (in this run, else the session's last); :class:`StoreError` if
        none. A landmark that replaced another is taken back alone: the one it replaced stays on record only."""
        stored = [n.id for n in self.session.intraop_records(kind=None)]
        while self._stored_here and self._stored_here[-1] not in stored:
            self._stored_here.pop()
        target = self._stored_here.pop() if self._stored_here else (stored[-1] if stored else None)
        if target is None:
            raise StoreError("there is no stored node to undo")
        return self.session.remove_intraop_node(target)

    def _imu_problem(self) -> str:
        """Why the window's trocar positions cannot be trusted for want of an IMU, in words; "" when they can."""
        if not self.imu_required:
            return ""
        readings = [(f.imu_state, f.imu_gap_s) for f in self._fixes]
        if self._last_imu is not None:
            readings.append((self._last_imu.state, self._last_imu.gap_s))
        if any(state == IMU_ABSENT for state, _ in readings):
            return ("there is no IMU, so the tip cannot be followed into the trocar frame; connect the IMU, "
                    "or start the session without one (Devices: IMU none)")
        state, gap = max(readings, key=lambda r: r[1])
        if gap > self.limits.imu_stale_s:
            return (f"the IMU is stale: no sample within {gap:.1f} s of a frame (IMU {state}), so the tip cannot be "
                    "mapped into the trocar frame; reconnect the IMU and store again")
        return ""

    def _away_from_stored(self, here: np.ndarray) -> bool:
        """Auto-store rule, for a full and still window with median ``here``: away from every stored node and landmark
        (the probe resting on a landmark just stored is not a new node)."""
        stored = [node.xyz_trocar for node in self.session.intraop_records(kind=None)]
        return not stored or float(np.min(np.linalg.norm(np.array(stored) - here, axis=1))) > AUTO_STORE_SEPARATION_MM

    def _window_trocar(self):
        """Median and spread of the full store window in the trocar frame; None until full."""
        if len(self._fixes) < self.fixes_per_node:
            return None
        return summarise(np.array([f.trocar for f in self._fixes]))
