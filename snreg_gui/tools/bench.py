"""How long the GUI thread is blocked during acquisition, and whether the recording keeps one clock:
``python -m snreg_gui.bench [--seconds S] [--json] [--keep SESSION.h5] [--no-video] [--camera still|surgery]
[--rendered] [--stalls]``.

Why: the technician's screen must never freeze while frames are tracked and nodes stored (issue 6: no stall
over 50 ms). A 10 ms heartbeat timer on the GUI thread ticks while the demo acquires (rendered feeds tracked
in the worker, the IMU on its pty, auto-store writing nodes); the gaps between ticks are the stalls. The
recorded session is then read back (:func:`~snreg.session.timeline.clock_figures`, issue 12): where the frame,
probe and IMU streams end, the longest frame gap, how far each stored node is from a probe fix. Both feeds are
recorded as the app records them (``--no-video``: not), and the video's cost is reported: frames written and dropped,
the encoder's CPU seconds per second of video (the cores it keeps busy), with how many pairs the worker processed
per second while measured, and the CPU each thread spent (in cores: the GUI thread, the acquisition worker, the
insertion's thread beside it, the IMU reader, the demo's renderer, the rest of the process, and the tracking process
where the pairs are tracked (issue 36) with "app" the two processes together, and the rest of the process's threads
by name; :mod:`snreg_gui.tools.thread_cpu`), in
all and per processed pair (the budget of a pair; what a thread spends per
second whatever the pairs, the IMU reader's, weighs more per pair when few are processed), so the app's own cost is
seen apart from the simulated camera's. Each stall over the target is split (Linux: the GUI thread's scheduler
statistics read at each tick; :func:`~snreg_gui.tools.stall_stacks.stall_split`) into the time the thread ran, waited
for a CPU (the machine's load, not the app) and slept (a lock: the interpreter's, held by another thread, or another).
``--rendered`` starts measuring once the surgery demo has rendered its whole tour (it renders as it plays, about a core
until then), so the figures are the app's alone. ``--stalls``: where the GUI thread was while it stalled
(:mod:`snreg_gui.tools.stall_stacks`). ``--keep`` records into SESSION.h5 and leaves it there; without it everything
the run wrote (session, journal, videos, SPECT, settings) is deleted at the end. Runs offscreen unless a display is set;
the numbers belong here, not in timed tests.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
from PySide6.QtCore import QSettings, Qt, QTimer

from snreg_gui.tools.stall_stacks import SAMPLE_S, StallSampler, sched_times, stall_split
from snreg_gui.tools.thread_cpu import cores_by_name, cores_by_role, process_cpu_s, thread_cpu_s, thread_names

TICK_MS = 10
# threads with a CPU figure of their own, by the start of their names: the insertion's images made beside the probe
# tracker (snreg.workflow.pair_tracking; in this process only when the worker tracks the pairs itself), the IMU's serial reader and fusion (snreg.imu.reader), the surgery demo's renderer, the
# simulated camera (snreg.demo.rig)
NAMED_THREADS = {"insertion": "snreg-insertion", "imu reader": "imu-reader", "demo renderer": "demo-tour-renderer"}
# the live loop's tracking process (snreg.workflow.tracking_process), a row of its own beside this process's threads
# (its own "snreg-insertion" thread included), and "app": this process and it together (the encoder apart)
TRACKING_PROCESS = "tracking process"
TARGET_STALL_MS, TARGET_FPS, TARGET_ENCODER_CORES = 33.0, 25.0, 1.0      # issue 36: the live loop at 30 Hz
SAMPLED_FROM_MS = 25.0      # --stalls samples the GUI thread in every stall past this: those that near the target too


class Heartbeat:
    """A ``TICK_MS`` timer on the GUI thread; the gaps between its ticks are how long the thread was blocked, and
    its scheduler times read at each tick (Linux) what it did meanwhile (:func:`stall_split`)."""

    def __init__(self):
        self.ticks: list[float] = []
        self.sched: list[tuple[float, float]] = []        # (s running, s waiting for a CPU) at each tick
        self._schedstat = Path(f"/proc/self/task/{threading.get_native_id()}/schedstat")
        self.timer = QTimer(interval=TICK_MS, timeout=self._tick)
        self.timer.setTimerType(Qt.TimerType.PreciseTimer)
        self.timer.start()

    def _tick(self) -> None:
        self.ticks.append(time.perf_counter())
        times = sched_times(self._schedstat)
        if times is not None:
            self.sched.append(times)

    def stall_split(self) -> dict | None:
        """The stalls over the target (:data:`TARGET_STALL_MS`), split into running, waiting for a CPU and asleep."""
        return stall_split(self.ticks, self.sched, TARGET_STALL_MS)

    def stop(self) -> None:
        self.timer.stop()

    def gaps_ms(self) -> np.ndarray:
        return np.diff(self.ticks) * 1e3

    def max_gap_ms(self) -> float:
        return float(np.max(self.gaps_ms()))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m snreg_gui.bench", description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="acquisition time measured (default 20)")
    parser.add_argument("--json", action="store_true", help="one JSON object on stdout")
    parser.add_argument("--keep", metavar="SESSION.h5", help="record into this new session file and keep it")
    parser.add_argument("--no-video", action="store_true", help="do not record the feeds (to measure what it costs)")
    parser.add_argument("--camera", choices=("still", "surgery"), default="still", help="the demo's camera: still "
                        "(default) or surgery (sliding and turning between nodes, its insertion tracked)")
    parser.add_argument("--rendered", action="store_true", help="measure once the surgery demo has rendered its "
                        "whole tour: the simulated camera's rendering (about a core until then) is then not measured")
    parser.add_argument("--stalls", action="store_true", help="sample the GUI thread's stack during stalls and list "
                        "where it was most often")
    args = parser.parse_args(argv)
    if args.keep and Path(args.keep).exists():
        parser.error(f"{args.keep} exists already; choose a new file name for the kept session")
    if "DISPLAY" not in os.environ:
        os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    from PySide6.QtWidgets import QApplication
    app = QApplication.instance() or QApplication(sys.argv[:1])
    work = Path(tempfile.mkdtemp(prefix="snreg-bench-"))
    try:
        return _run(args, app, work)
    finally:
        shutil.rmtree(work, ignore_errors=True)             # nothing left behind but a kept session


def _run(args, app, work: Path) -> int:
    from snreg.demo.rig import DemoRig
    from snreg.demo.scene import Schedule
    from snreg.session.timeline import clock_figures
    from snreg_gui.app import MainWindow

    session_path = Path(args.keep) if args.keep else work / "bench.h5"
    settings = QSettings(str(work / "settings.ini"), QSettings.Format.IniFormat)
    settings.setValue("acquisition/record_video", not args.no_video)
    # 8 s rests: the live feed skips frames when the worker lags, so a loaded machine still gathers 60 fixes per node
    rig = DemoRig(schedule=Schedule(rest_frames=240), camera=args.camera)
    window = MainWindow(str(session_path), demo=True, rig=rig, settings=settings)
    window.show()
    frames: list[int] = []
    processed_at: list[float] = []           # when each processed pair reached the GUI thread
    worker_thread: set[int] = set()          # the worker's native thread id (its signal, called where it is emitted)

    def processed(result) -> None:
        frames.append(result.outcome.index)
        processed_at.append(time.perf_counter())
    window.worker.frame_processed.connect(processed)
    window.worker.frame_processed.connect(lambda _: worker_thread.add(threading.get_native_id()),
                                          Qt.ConnectionType.DirectConnection)
    window.acquisition.auto_store.setChecked(True)
    stopped: list[str] = []
    window.worker.source_stopped.connect(stopped.append)
    while not frames or (args.rendered and rig.preparing):     # the first frame comes once the IMU holds still
        if stopped:
            window.shutdown()
            raise SystemExit(f"bench: the demo feed did not start: {stopped[0]}")
        app.processEvents()
        time.sleep(0.01)
    encoder = window.session.video_state()             # updated in place until the session closes
    heartbeat = Heartbeat()
    sampler = (StallSampler(lambda: heartbeat.ticks[-1] if heartbeat.ticks else None, late_ms=SAMPLED_FROM_MS)
               if args.stalls else None)
    named = {role: next((t.native_id for t in threading.enumerate() if t.name.startswith(prefix)), None)
             for role, prefix in NAMED_THREADS.items()}
    cpu_before, cpu_after = thread_cpu_s(), {}       # the latest reading of each thread (one may end meanwhile)
    names = thread_names()                           # each thread's name, for the other threads' breakdown
    tracking_pid = window.worker.acquisition.tracking_pid       # the tracking process (None: tracked in the worker)
    tracking_cpu = [process_cpu_s(tracking_pid)] if tracking_pid is not None else []

    def read_cpu() -> None:
        cpu_after.update(thread_cpu_s())
        names.update(thread_names())
        if tracking_cpu:
            spent = process_cpu_s(tracking_pid)
            tracking_cpu[1:] = [spent] if spent is not None else tracking_cpu[1:]     # its latest, while it lived
    cpu_timer = QTimer(interval=1000, timeout=read_cpu)
    cpu_timer.start()
    process_before, process_spent = _process_cpu_s(), []

    def end() -> None:          # the heartbeat stops first: closing the window (0.5 s) is not acquisition
        heartbeat.stop()
        if sampler is not None:
            sampler.stop()
        cpu_timer.stop()
        read_cpu()
        process_spent.append(_process_cpu_s() - process_before)
        window.quit_without_asking()
    QTimer.singleShot(round(args.seconds * 1000), end)
    app.exec()                                          # the app's own event loop, as in use
    gaps = heartbeat.gaps_ms()
    roles = {"gui": threading.get_native_id(), "worker": min(worker_thread, default=None), **named}
    seconds = heartbeat.ticks[-1] - heartbeat.ticks[0]
    cores = cores_by_role(cpu_before, cpu_after, roles, seconds, process_spent[0] if process_spent else None)
    others = cores_by_name(cpu_before, cpu_after, names, seconds, leave_out=set(roles.values()))
    if cores and len(tracking_cpu) == 2 and tracking_cpu[0] is not None:
        cores[TRACKING_PROCESS] = round((tracking_cpu[1] - tracking_cpu[0]) / seconds, 3)
        cores["app"] = round(cores["process"] + cores[TRACKING_PROCESS], 3)
    measured = [t for t in processed_at if heartbeat.ticks[0] <= t <= heartbeat.ticks[-1]]
    fps = len(measured) / max(heartbeat.ticks[-1] - heartbeat.ticks[0], 1e-9)
    stored = window.acquisition.nodes.rowCount()
    window.shutdown()
    settings.sync()              # written now, so nothing rewrites the folder once it is deleted
    video = _video_figures(session_path, encoder)
    result = {"seconds": args.seconds, "camera": args.camera, "rendered_first": args.rendered, "frames": len(frames),
              "nodes_stored": stored,
              "ticks": len(gaps) + 1, "processed_fps": round(fps, 1),
              "max_gap_ms": round(float(gaps.max()), 1), "p99_gap_ms": round(float(np.percentile(gaps, 99)), 1),
              "median_gap_ms": round(float(np.median(gaps)), 1), "stall_split": heartbeat.stall_split(),
              "platform": app.platformName(),
              "clock": clock_figures(session_path), "video": video, "cores": cores, "other_threads": others,
              "cpu_ms_per_pair": {name: round(1e3 * value / fps, 1) for name, value in cores.items()} if fps else {},
              "stalls": [{"stack": stack, "samples": n} for stack, n in sampler.top()] if sampler else None,
              "session": str(session_path) if args.keep else None}
    if args.json:
        print(json.dumps(result))
    else:
        print(f"GUI thread during {args.seconds:.0f} s of {args.camera} demo acquisition ({result['frames']} frames, "
              f"{stored} nodes auto-stored, {result['platform']}): longest stall {result['max_gap_ms']} ms, "
              f"p99 {result['p99_gap_ms']} ms, median tick gap {result['median_gap_ms']} ms (timer {TICK_MS} ms); "
              f"{result['processed_fps']} pairs processed per second")
        split = result["stall_split"]
        if split:
            print(f"{split['stalls']} stalls over {TARGET_STALL_MS:.0f} ms, {split['ms']} ms in all: the GUI thread "
                  f"running {split['running_ms']} ms, waiting for a CPU {split['waiting_for_cpu_ms']} ms (the "
                  f"machine's load), asleep {split['asleep_ms']} ms (a lock: the interpreter's, held by another thread, or "
                  f"another); the longest ({split['longest']['ms']} ms): {split['longest']['running_ms']}, "
                  f"{split['longest']['waiting_for_cpu_ms']} and {split['longest']['asleep_ms']} ms")
        clock = result["clock"]
        if video:
            print(f"video: {video['frames']} frames recorded, {video['dropped']} dropped; encoder "
                  f"{video['encoder_cpu_s_per_video_s']} CPU s per s of video (cores), {video['mb_per_min']} MB per "
                  f"minute ({video['frame_size'][0]}x{video['frame_size'][1]})")
        if cores:
            print("CPU while measured, cores: " + ", ".join(f"{name} {value}" for name, value in cores.items())
                  + " (the demo renderer is the simulated camera, not the app; the tracking process and the "
                  "encoder are processes of their own, app = process + tracking process); "
                  "per processed pair, ms: " + ", ".join(f"{name} {value}" for name, value in
                                                           result["cpu_ms_per_pair"].items()))
        if others:
            print("other threads by name, cores: " + ", ".join(f"{name} {value}" for name, value in others.items()))
        for stack, n in (sampler.top() if sampler else []):
            print(f"stalled {n * SAMPLE_S * 1e3:.0f} ms (beyond {SAMPLED_FROM_MS:.0f} ms) in: {stack}")
        print(f"targets (issue 36, a quiet machine): stalls at most {TARGET_STALL_MS} ms, at least {TARGET_FPS} pairs "
              f"processed per second, the encoder at most {TARGET_ENCODER_CORES} core")
        print(f"one clock: streams end at {clock['ends_s']} s (spread {clock['end_spread_s']} s), longest frame gap "
              f"{clock['max_frame_gap_s']} s, stored nodes at most {clock['max_node_to_fix_s']} s from a probe fix"
              + (f"; session kept in {session_path}" if args.keep else ""))
    return 0



def _process_cpu_s() -> float:
    """CPU seconds this process spent so far, every thread's, ended ones' too (not its child processes')."""
    times = os.times()
    return times.user + times.system


def _video_figures(session_path: Path, encoder) -> dict | None:
    """What recording the feeds did and cost: frames, drops, encoder CPU s per s of video, size; None when off."""
    from snreg.session import Session
    with Session.open(session_path) as session:
        segments = session.videos()
    if not segments or encoder is None:
        return None
    frames, dropped = sum(s.frames[0] for s in segments), sum(s.dropped for s in segments)
    seconds = frames / segments[0].fps
    size = sum(sum(s.size) for s in segments)
    return {"frames": frames, "dropped": dropped, "size_mb": round(size / 1e6, 1),
            "mb_per_min": round(size / 1e6 / max(seconds, 1e-9) * 60, 1),
            "encoder_cpu_s_per_video_s": round(encoder.cpu_s / max(seconds, 1e-9), 3),
            "frame_size": [segments[0].width, segments[0].height]}
