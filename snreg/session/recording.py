"""What a session being recorded writes: nodes, undo, re-expressions, events, calibrations, preop nodes,
registrations, the final mark and the streams, each journal first and durable when its method returns."""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import replace
import time

import numpy as np

from snreg.landmarks import LANDMARK, NODE, kind_of, landmark_name
from snreg.nodes import INTRAOP_PREFIX, NodeSet
from snreg.preop.gravity import PreopDown
from snreg.session import writer
from snreg.session.schema import (CAMERA_STATES, STREAM_DTYPES, IntraopNode, SessionError, covariance_json,
                                  covariance_mm2, jpeg_bytes, landmark_results_json, position_mm, stereo_to_dict)
from snreg.session.video import MIN_FREE_BYTES, RecorderState, StereoRecorder, VideoSegment, free_bytes, segment_files


def serialised(method):
    """Run a writing method under the session's lock: the acquisition worker (nodes, streams) and the
    registration panel's worker (preop, results) may write at the same time from their own threads."""
    @functools.wraps(method)
    def locked(self, *args, **kwargs):
        with self._lock:
            return method(self, *args, **kwargs)
    return locked


class Recording:
    """The writing half of :class:`~snreg.session.session.Session`, on the state its constructor sets up (the open
    HDF5 file, the journal, the merged contents and the lock)."""

    @serialised
    def add_intraop_node(self, node_id: str, label: str, xyz_trocar, *, xyz_camera=None, spread_mm: float = float("nan"),
                         n_frames: int = 0, counts: float = float("nan"), time_ns: int | None = None,
                         left_jpeg=b"", right_jpeg=b"", earth_from_imu=None, stereo_version: str = "",
                         chain_version: str = "", trocar_camera_mm: float = float("nan"),
                         cov_trocar_mm2=None, kind: str = NODE) -> IntraopNode:
        """Store a node (positions mm; time ns on the host clock, perf_counter_ns like the streams); on disk when this returns.

        Snapshots are JPEG bytes or images (H, W[, 3]) uint8, encoded here. ``earth_from_imu`` (3, 3), the
        calibration versions and ``trocar_camera_mm`` (the tracked insertion it was mapped with, NaN when untracked)
        say what the node was measured with; ``cov_trocar_mm2`` (3, 3) its own error's covariance, mm^2, trocar
        frame (None: unknown) (see :class:`IntraopNode`). ``kind="landmark"`` stores an anatomical landmark instead,
        ``node_id`` its name (:func:`snreg.landmarks.landmark_name`); ids and names share one namespace.
        """
        self._writable()
        try:
            kind = kind_of(kind)
            node_id = landmark_name(node_id) if kind == LANDMARK else str(node_id)
        except ValueError as err:
            raise SessionError(str(err)) from None
        if node_id in self._nodes:
            what = "landmark" if self._nodes[node_id].kind == LANDMARK else "node"
            raise SessionError(f"{self.path}: {what} {node_id!r} is already stored; "
                               + ("take it back first to store it again" if kind == LANDMARK else "use a new id"))
        nan3 = np.full(3, np.nan)
        node = IntraopNode(node_id, str(label), time.perf_counter_ns() if time_ns is None else int(time_ns),
                           position_mm(xyz_trocar), nan3 if xyz_camera is None else position_mm(xyz_camera), float(spread_mm),
                           int(n_frames), float(counts), jpeg_bytes(left_jpeg), jpeg_bytes(right_jpeg),
                           np.full((3, 3), np.nan) if earth_from_imu is None
                           else np.asarray(earth_from_imu, dtype=float).reshape(3, 3),
                           str(stereo_version), str(chain_version), float(trocar_camera_mm),
                           covariance_mm2(cov_trocar_mm2), kind)
        self._journal.append("node", node.to_json())
        writer.write_node(self._h5, node)
        self._h5.flush()
        self._nodes[node_id] = node
        return node

    @serialised
    def remove_intraop_node(self, node_id: str) -> IntraopNode:
        """Take back a stored node or landmark (undo); durable when this returns. The journal keeps it on record."""
        self._writable()
        node_id = str(node_id)
        if node_id not in self._nodes:
            raise SessionError(f"{self.path}: there is no stored node {node_id!r} to remove")
        self._journal.append("node_removed", {"id": node_id})
        node = self._nodes.pop(node_id)
        writer.rewrite_nodes(self._h5, list(self._nodes.values()))
        self._h5.flush()
        return node

    @serialised
    def reexpress_nodes(self, nodes: list[IntraopNode], reason: str) -> dict:
        """Replace stored nodes by the same nodes re-expressed (new positions, calibration versions, insertion and
        covariance, same ids), all or none: one journal line holds them with their old values, which stay on record
        in the ``events`` log (kind ``nodes_reexpressed``). Returns that event."""
        self._writable()
        missing = [node.id for node in nodes if node.id not in self._nodes]
        if missing:
            raise SessionError(f"{self.path}: there is no stored node {missing[0]!r} to re-express")
        keys = ("xyz_trocar", "xyz_camera", "stereo_version", "chain_version", "trocar_camera_mm", "cov_trocar_mm2")
        changes = []
        for node in nodes:
            old = self._nodes[node.id]
            changes.append({"id": node.id, **_plain_values(node, keys),
                            "old": _plain_values(old, keys)})
        event = {"n": len(self._events), "kind": "nodes_reexpressed", "time_ns": time.perf_counter_ns(),
                 "reason": str(reason), "nodes": changes}
        self._journal.append("nodes_reexpressed", event)
        self._apply_reexpression(event)
        self._events.append(event)
        writer.rewrite_nodes(self._h5, list(self._nodes.values()))
        writer.append_event(self._h5, event)
        self._h5.flush()
        return event

    def _apply_reexpression(self, event: dict) -> None:
        for change in event["nodes"]:
            node = self._nodes.get(change["id"])
            if node is not None:
                self._nodes[node.id] = dataclasses.replace(
                    node, xyz_trocar=np.asarray(change["xyz_trocar"], dtype=float),
                    xyz_camera=np.asarray(change["xyz_camera"], dtype=float),
                    stereo_version=str(change["stereo_version"]), chain_version=str(change["chain_version"]),
                    trocar_camera_mm=float(change.get("trocar_camera_mm", node.trocar_camera_mm)),
                    cov_trocar_mm2=covariance_mm2(change.get("cov_trocar_mm2")))   # not stated: unknown

    @serialised
    def log_event(self, kind: str, **data) -> dict:
        """Put what happened (``kind``, e.g. ``store_refused`` with its ``reason``) on record, durable on return;
        host time ns is added. Returns the event."""
        self._writable()
        event = {"n": len(self._events), "kind": str(kind), "time_ns": time.perf_counter_ns(), **data}
        self._journal.append("event", event)
        writer.append_event(self._h5, event)
        self._h5.flush()
        self._events.append(event)
        return event

    def next_node_id(self, prefix: str = INTRAOP_PREFIX) -> str:
        """The first ``<prefix><k>`` (k = 1, 2, ...) not stored: after an undo the id is used again."""
        k = 1
        while f"{prefix}{k}" in self._nodes:
            k += 1
        return f"{prefix}{k}"

    @property
    def writable(self) -> bool:
        return self._journal is not None

    @serialised
    def set_calibration(self, *, stereo=None, chain=None) -> None:
        """Store a :class:`~snreg.camera.StereoCalibration` and/or a :class:`~snreg.chain.ChainCalibration`."""
        self._writable()
        items = ([("stereo", stereo_to_dict(stereo))] if stereo is not None else []) + \
                ([("chain", chain.to_dict())] if chain is not None else [])
        for kind, data in items:
            self._journal.append("calibration", {"kind": kind, "data": data})
            writer.write_calibration(self._h5, kind, data)
            self._calibration[kind] = data
        self._h5.flush()

    @serialised
    def set_preop_nodes(self, nodes: NodeSet, landmarks: NodeSet | None = None, down: PreopDown | None = None) -> None:
        """Store the preop node set (ids, labels, positions, counts and each hot spot's covariance when known), the
        preop landmarks read with it (ids = names, in the nodes' frame; None or empty: none) and what gives the down in
        its frame (the SPECT's patient position and the table's tilt; None: unknown). All replace what was stored: a
        preop set given without its landmarks or its down leaves the session without them."""
        self._writable()
        marks = None
        if landmarks is not None and len(landmarks):
            try:
                names = NodeSet([landmark_name(name) for name in landmarks.ids], landmarks.labels, landmarks.xyz).ids
            except ValueError as err:
                raise SessionError(f"the preop landmarks cannot be stored: {err}") from None
            marks = {"ids": names, "labels": list(landmarks.labels), "xyz": landmarks.xyz.tolist()}
        data = {"ids": nodes.ids, "labels": nodes.labels, "xyz": nodes.xyz.tolist(),
                "counts": None if nodes.counts is None else nodes.counts.tolist(), "frame": nodes.frame,
                "cov": None if nodes.cov is None else nodes.cov.tolist(), "landmarks": marks,
                "down": None if down is None else down.to_json()}
        self._journal.append("preop", data)
        writer.write_preop(self._h5, data)
        self._h5.flush()
        self._preop = data

    @serialised
    def add_registration(self, result, preop_ids, intraop_ids) -> int:
        """Store a :class:`~snreg.registration.RegistrationResult` as ``registration/<n>`` with the ids of the preop
        and intraop nodes it paired (so it stays readable after an undo or a re-segmentation), the initial
        alignment it started from and, when landmarks took part, each pair's residuals and the suspects; returns n."""
        self._writable()
        preop_ids, intraop_ids = [str(i) for i in preop_ids], [str(i) for i in intraop_ids]
        pairing = np.asarray(result.pairing, dtype=int)
        if len(intraop_ids) != len(pairing) or int(pairing.max(initial=-1)) >= len(preop_ids):
            raise SessionError(f"{self.path}: the registration pairs {len(pairing)} intraop nodes with preop indices "
                               f"up to {int(pairing.max(initial=-1))}, but {len(intraop_ids)} intraop and "
                               f"{len(preop_ids)} preop ids were given; give the ids of the node sets it was run on")
        def optional(name):
            value = getattr(result, name, None)
            return None if value is None else np.asarray(value).tolist()

        data = {"n": len(self._registrations), "method": result.method, "rms_mm": float(result.rms_mm),
                "pairing_rule": result.pairing_rule, "transform": np.asarray(result.transform).tolist(),
                "pairing": pairing.tolist(), "distances_mm": np.asarray(result.distances_mm).tolist(),
                "confidence": np.asarray(result.confidence).tolist(), "preop_ids": preop_ids,
                "intraop_ids": intraop_ids,
                **{name: optional(name) for name in ("initial", "target_error_mm", "missing", "leave_one_out_mm")},
                "landmarks": landmark_results_json(result)}
        self._journal.append("registration", data)
        writer.write_registration(self._h5, data)
        self._h5.flush()
        self._registrations.append(data)
        return data["n"]

    @serialised
    def set_final_registration(self, n: int | None) -> None:
        """Mark stored registration ``n`` as the final one, the one that counts (exports use it); None unmarks.
        At most one is final: marking another moves the mark. Durable when this returns (journal line, then the
        ``final`` attribute on ``registration/<n>`` and a flush); no node or registration data is rewritten."""
        self._writable()
        n = self._known_registration(n)
        self._journal.append("final", {"n": n})
        writer.write_final(self._h5, n)
        self._h5.flush()
        self._final = n

    def _known_registration(self, n: int | None) -> int | None:
        if n is None:
            return None
        if int(n) not in {r["n"] for r in self._registrations}:
            raise SessionError(f"{self.path}: there is no stored registration {n} to mark final; "
                               f"stored: {', '.join(str(r['n']) for r in self._registrations) or 'none'}")
        return int(n)

    def append_imu(self, t_host_ns, t_device_ns, acc_g, gyro_dps) -> None:
        """IMU samples: times (n,) ns, acceleration (n, 3) g, angular rate (n, 3) deg/s."""
        self._append("imu", t_host_ns=t_host_ns, t_device_ns=t_device_ns, acc_g=acc_g, gyro_dps=gyro_dps)

    def append_probe(self, t_host_ns, t_device_ns, tip_mm, centre_mm, axis, quality) -> None:
        """Probe poses: times (n,) ns, tip and centre (n, 3) mm camera frame, axis (n, 3) unit, quality (n,)."""
        self._append("probe", t_host_ns=t_host_ns, t_device_ns=t_device_ns, tip_mm=tip_mm, centre_mm=centre_mm,
                     axis=axis, quality=quality)

    def append_camera(self, t_host_ns, t_device_ns, trocar_camera_mm, state, quality, residual_mm, sd_mm) -> None:
        """The camera's tracked insertion (``streams/camera``): its pairs' grab times (n,) ns (left as host, right as
        device, as the probe rows), the insertion (n,) mm (NaN when lost), ``state`` "tracked" | "lost" (one or
        (n,)), quality (n,) 0-1, the pivot model's residual and the insertion's standard error (n,) mm."""
        names = np.atleast_1d(np.asarray(state, dtype=object))
        unknown = {str(v) for v in names} - set(CAMERA_STATES)
        if unknown:
            raise SessionError(f"a camera state must be one of {', '.join(CAMERA_STATES)}, got {sorted(unknown)[0]!r}")
        codes = np.array([CAMERA_STATES.index(str(v)) for v in names], dtype=np.uint8)
        codes = np.broadcast_to(codes, np.atleast_1d(t_host_ns).shape)          # one state for every row, or one each
        self._append("camera", t_host_ns=t_host_ns, t_device_ns=t_device_ns, trocar_camera_mm=trocar_camera_mm,
                     state=codes, quality=quality, residual_mm=residual_mm, sd_mm=sd_mm)

    def append_frames(self, t_host_ns, t_device_ns, index) -> None:
        """Frame times (n,) ns and frame indices (n,)."""
        self._append("frames", t_host_ns=t_host_ns, t_device_ns=t_device_ns, index=index)

    @serialised
    def _append(self, name: str, **columns) -> None:
        self._writable()
        n = np.atleast_1d(columns["t_host_ns"]).shape[0]
        rows = np.zeros(n, STREAM_DTYPES[name])
        for key, value in columns.items():
            rows[key] = np.asarray(value).reshape(rows[key].shape)
        self._buffers[name].append(rows)

    # -- video ---------------------------------------------------------------
    @serialised
    def start_video(self, fps: float, width: int, height: int, *, min_free_bytes: int = MIN_FREE_BYTES,
                    wait_s: float = 0.0) -> VideoSegment:
        """Record the pairs given to :meth:`append_frame_pair` into a new segment of two files beside the session
        (the one being recorded is finished first); OSError when the disk is short of ``min_free_bytes`` (files
        that cannot be written stop the recording: :meth:`video_state` says why). Its frame 0 is the row of the
        first pair the encoder takes, a second or two after the start; ``wait_s``: wait that long at most for the
        encoder to start (from the acquisition's thread, before its first frame)."""
        self._writable()
        self.stop_video()
        free = free_bytes(self.path.parent)
        if free < min_free_bytes:
            raise OSError(f"only {free / 1e9:.1f} GB free beside {self.path.name}; the video is not recorded "
                          f"(it needs {min_free_bytes / 1e9:.0f} GB); free some space")
        n = max(self._videos, default=-1) + 1
        segment = VideoSegment(n, segment_files(self.path, n), self._buffers["frames"].rows, float(fps), int(width),
                               int(height))
        self._recorder = StereoRecorder(self.path, segment, min_free_bytes=min_free_bytes)
        self._record_segment(segment)
        self._video_waiting = True                  # its first_row is set again when the encoder takes a pair
        deadline = time.monotonic() + wait_s
        while not self._recorder.state.started and not self._recorder.state.problem and time.monotonic() < deadline:
            time.sleep(0.01)
        return segment

    @serialised
    def append_frame_pair(self, t_left_ns, t_right_ns, index, left, right) -> bool:
        """A frame row, and the pair into the video being recorded if one is (:meth:`start_video`) and its encoder
        has started. False when the encoder was behind: the pair was dropped and no row written (rows and video
        frames stay in step; the drop is counted in :meth:`video_state`)."""
        self._writable()
        recorder = self._recorder
        if recorder is not None and recorder.ready:
            if self._video_waiting:                 # the encoder's first pair: frame 0 is this row
                self._video_waiting = False
                recorder.segment = replace(recorder.segment, first_row=self._buffers["frames"].rows)
                self._record_segment(recorder.segment)
            if not recorder.offer(left, right) and recorder.recording:
                return False                        # behind, not stopped: the pair is dropped
        self.append_frames(t_left_ns, t_right_ns, index)
        return True

    @serialised
    def stop_video(self) -> VideoSegment | None:
        """Finish the video being recorded: its frames, sizes and SHA-256 go on record; None when none was."""
        recorder, self._recorder = self._recorder, None
        if recorder is None:
            return None
        segment = recorder.close()
        self._record_segment(segment)
        return segment

    def video_state(self) -> RecorderState | None:
        """What the video encoder has done (written, dropped, why it stopped), None while nothing is recorded."""
        recorder = self._recorder
        return None if recorder is None else recorder.state

    def _record_segment(self, segment: VideoSegment) -> None:
        data = segment.to_json()
        self._journal.append("video", data)
        writer.write_video(self._h5, data)
        self._h5.flush()
        self._videos[segment.n] = data

    def _writable(self) -> None:
        if self._journal is None:
            raise SessionError(f"{self.path}: opened for reading; create a new session to record")


def _plain_values(node: IntraopNode, keys) -> dict:
    def plain(key):
        value = getattr(node, key)
        if key.startswith("xyz"):
            return np.asarray(value, dtype=float).tolist()
        if key == "cov_trocar_mm2":
            return covariance_json(value)
        return float(value) if key == "trocar_camera_mm" else str(value)
    return {key: plain(key) for key in keys}

