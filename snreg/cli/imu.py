"""``snreg imu monitor`` and ``snreg imu simulate`` (docs/design.md, Contracts): live angles from a port, and the simulator."""

from __future__ import annotations

import contextlib
import json
import os
import queue
import signal
import sys
import threading
import time

from snreg.cli.common import check_output_file, float_range, floats, fraction, int_range, positive_int, seed, writing
from snreg.errors import UserError

__all__ = ["add_imu_parser", "cmd_imu_monitor", "cmd_imu_simulate"]

DEFAULT_BAUD = 230400        # snreg.imu.reader.DEFAULT_BAUD, the firmware's (a test keeps them equal)
_QUEUE_SIZE = 1 << 17         # ~10 min at 208 Hz: the monitor never falls that far behind
_STATUS_EVERY_S = 0.2
MAX_BAUD = 12_000_000         # the fastest USB serial adapters
MAX_SECONDS = 7 * 86400.0
MIN_RATE_HZ, MAX_RATE_HZ = 1.0, 6667.0     # the LSM6DSOX's output data rates run from 1.6 Hz (low power) to 6667 Hz


def add_imu_parser(subparsers) -> None:
    """Add ``imu monitor`` and ``imu simulate`` to the ``snreg`` subcommands."""
    p = subparsers.add_parser("imu", help="the endoscope IMU: live monitor and simulator")
    imu = p.add_subparsers(dest="imu_command", required=True)

    m = imu.add_parser("monitor", help="live yaw, pitch and roll from an IMU serial port")
    m.add_argument("port", help="serial port: /dev/ttyACM0, COM3, or a simulator's pty or --port-link")
    m.add_argument("--baud", type=int_range(50, MAX_BAUD), default=DEFAULT_BAUD, help="bits per second, as the firmware")
    m.add_argument("--seconds", type=float_range(0, MAX_SECONDS, "s"),
                   help="stop after this many seconds, at most a week (default: at Ctrl-C)")
    m.add_argument("--csv", help="write t_host_s,t_device_s,yaw,pitch,roll per sample (s since start, device s, degrees)")
    m.add_argument("--json", action="store_true", help='print {"samples", "corrupt", "dropped"} as JSON at exit')
    m.set_defaults(func=cmd_imu_monitor)

    s = imu.add_parser("simulate", help="an IMU on a pseudo-terminal, protractor moves or a replayed CSV (until Ctrl-C)")
    s.add_argument("--port-link", help="also make this symlink to the pty, e.g. /tmp/snreg-imu")
    s.add_argument("--rate", type=float_range(MIN_RATE_HZ, MAX_RATE_HZ, "Hz", low_open=False),
                   help=f"sample rate in Hz, {MIN_RATE_HZ:g} to {MAX_RATE_HZ:g} as the LSM6DSOX (default 208)")
    s.add_argument("--replay", help="play a recorded CSV (Time (s), Gyroscope X (deg/s), ..., Accelerometer X (g), ...)")
    s.add_argument("--seed", type=seed, default=0, help="seed for noise, bias and faults")
    s.add_argument("--garbage", type=fraction, default=0.0, help="fraction of samples that come with a corrupt line")
    s.add_argument("--dropout", type=fraction, default=0.0, help="fraction of samples skipped")
    s.add_argument("--still", action="store_true", help="hold the sensor still and level instead of the protractor "
                   "moves (the demo rig's still endoscope)")
    s.add_argument("--attitude", type=floats, metavar="YAW,PITCH,ROLL",
                   help="with --still: hold the sensor at this orientation instead of level (degrees, earth from "
                        "sensor, z up, R = Rz Ry Rx as the IMU reports it; the demo rig's endoscope in its patient)")
    s.add_argument("--motion", metavar="FILE", help="play the motion profile in this JSON file (segments, initial "
                   "orientation, repeat; as snreg.demo.imu_motion.MotionProfile.to_dict writes it) instead")
    s.add_argument("--hold", type=float_range(0, MAX_SECONDS, "s", low_open=False), default=0.0, metavar="S",
                   help="hold the motion's first pose this long after the stream starts (a reader opened the port), "
                        "so the fusion starts still")
    s.add_argument("--epoch-file", metavar="PATH", help="when the stream starts, write there the host time at which "
                   "the motion starts (time.perf_counter_ns(), shared by the processes of this computer), so another "
                   "program shows the same motion in step; the lines then keep to that schedule")
    s.add_argument("--timeline-stdin", action="store_true",
                   help="with --motion: the motion waits at its start until runs arrive on standard input, one line "
                        "each: START FROM UNTIL (seconds from the motion's start: from clock time START the motion "
                        "plays from FROM until UNTIL, then holds; the demo rig holding a rest until its node is "
                        "stored); the serial protocol is unchanged")
    s.add_argument("--parent", type=positive_int, metavar="PID",
                   help="stop when process PID, the program that started this simulator, ends")
    s.set_defaults(func=cmd_imu_simulate)


class _AngleLog:
    """Fuses samples into (yaw, pitch, roll) degrees and writes them as CSV rows (host s since start,
    device s with the 32-bit microsecond clock unwrapped)."""

    def __init__(self, fusion_class, reader, out):
        self._fusion_class, self._reader, self._out = fusion_class, reader, out
        from snreg.imu.protocol import DEVICE_CLOCK_WRAP_US

        self._wrap_us = DEVICE_CLOCK_WRAP_US
        self._fusion = None
        self._t0_ns = time.perf_counter_ns()
        self._last_us, self._wraps = None, 0
        self.angles = (0.0, 0.0, 0.0)

    def add(self, sample) -> None:
        if self._fusion is None:
            self._fusion = self._fusion_class(self._reader.rate_hz)
        self.angles = yaw, pitch, roll = self._fusion.update(sample)
        if self._last_us is not None and self._last_us - sample.t_device_us > self._wrap_us // 2:
            self._wraps += 1
        self._last_us = sample.t_device_us
        if self._out:
            t_device_s = (self._wraps * self._wrap_us + sample.t_device_us) / 1e6
            self._out.write(f"{(sample.t_host_ns - self._t0_ns) / 1e9:.6f},{t_device_s:.6f},"
                            f"{yaw:.4f},{pitch:.4f},{roll:.4f}\n")


def cmd_imu_monitor(args) -> int:
    """Show live angles until ``--seconds`` or Ctrl-C; with ``--csv`` the samples go to a temporary file beside the
    target, renamed over it at the end (a full disk ends the run with one line and leaves nothing behind)."""
    from snreg.imu.fusion import Fusion
    from snreg.imu.reader import ImuPortError, SerialImuReader

    csv_path = check_output_file(args.csv, "IMU CSV") if args.csv else None
    reader = SerialImuReader(args.port, args.baud, queue_size=_QUEUE_SIZE)
    with contextlib.ExitStack() as files:
        out = None
        if csv_path is not None:
            out = files.enter_context(open(files.enter_context(writing(csv_path, "IMU CSV")), "w", encoding="utf-8",
                                           newline=""))
        log = _AngleLog(Fusion, reader, out)
        try:
            reader.start()
        except ImuPortError as err:
            raise UserError(str(err)) from None
        if out:
            out.write("t_host_s,t_device_s,yaw,pitch,roll\n")
        state, problem = _monitor(reader, log, args.seconds)
    c = reader.counts
    if args.json:
        print(json.dumps({"samples": c.samples, "corrupt": c.corrupt, "dropped": c.dropped}))
    else:
        last = f" (last: {reader.last_corrupt.reason})" if reader.last_corrupt else ""
        print(f"{c.samples} samples, {c.corrupt} corrupt{last}, {c.dropped} dropped; {state.value}"
              f"{': ' + problem if problem else ''}")
    return 0


def _monitor(reader, log: _AngleLog, seconds: float | None):
    """Feed the samples into ``log`` until the time is up or Ctrl-C; returns the reader's last state and problem."""
    live = sys.stderr.isatty()
    deadline = None if seconds is None else time.perf_counter() + seconds
    next_status = time.perf_counter()
    try:
        while deadline is None or time.perf_counter() < deadline:
            try:
                log.add(reader.queue.get(timeout=0.05))
            except queue.Empty:
                pass
            if live and time.perf_counter() >= next_status:
                next_status += _STATUS_EVERY_S
                (yaw, pitch, roll), c = log.angles, reader.counts
                print(f"\ryaw {yaw:8.2f}  pitch {pitch:7.2f}  roll {roll:7.2f} deg  {reader.state.value:<12} "
                      f"samples {c.samples}  corrupt {c.corrupt}  dropped {c.dropped}   ", end="", file=sys.stderr, flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        state, problem = reader.state, reader.problem
        reader.stop()
    while not reader.queue.empty():
        log.add(reader.queue.get_nowait())
    if live:
        print(file=sys.stderr)
    return state, problem


def cmd_imu_simulate(args) -> int:
    from scipy.spatial.transform import Rotation

    from snreg.demo.imu_motion import MotionProfile, protractor_profile, read_motion_file, still
    from snreg.demo.imu_simulator import CsvReplay, Faults, ImuSimulator, SimulatedPort
    from snreg.demo.motion_timeline import MotionTimeline, Run

    if args.parent is not None and args.parent != os.getppid():
        raise UserError(f"--parent {args.parent}: not the process that started this simulator (its parent is "
                        f"{os.getppid()}); give the PID of the program that starts it, or leave --parent out")
    chosen = [flag for flag, given in (("--replay", args.replay), ("--still", args.still), ("--motion", args.motion))
              if given]
    if len(chosen) > 1:
        raise UserError(f"{' and '.join(chosen)} each choose what the sensor does; give one of them")
    if args.replay and (args.hold or args.epoch_file):
        raise UserError("--hold and --epoch-file do not apply to --replay, which keeps the recording's times; "
                        "drop them")
    if args.timeline_stdin and not args.motion:
        raise UserError("--timeline-stdin paces the motion of --motion FILE; add --motion or drop it")
    if args.attitude is not None and (not args.still or len(args.attitude) != 3):
        raise UserError("--attitude holds the still sensor at YAW,PITCH,ROLL degrees: give three numbers, with --still")
    epoch_file = check_output_file(args.epoch_file, "epoch") if args.epoch_file else None
    timeline = MotionTimeline(Run(0.0, 0.0, 0.0)) if args.timeline_stdin else None     # held at its start until told
    try:
        faults = Faults(dropout_rate=args.dropout, garbage_rate=args.garbage)
        if args.replay:
            if args.rate is not None:
                raise UserError("--rate does not apply to --replay, which keeps the recording's times; drop one")
            source = CsvReplay(args.replay, faults=faults, seed=args.seed)
            what = f"replaying {args.replay} ({len(source.readings.t_s)} samples at {source.rate_hz:.1f} Hz)"
        else:
            rate = 208.0 if args.rate is None else args.rate
            if args.motion:
                motion, what = read_motion_file(args.motion), f"the motion of {args.motion}"
            elif args.still:
                attitude = None if args.attitude is None else Rotation.from_euler("ZYX", args.attitude, degrees=True)
                motion = MotionProfile([still(1.0)], attitude)
                what = "held still and " + ("level" if attitude is None else
                                            "at yaw, pitch, roll " + ", ".join(f"{v:g}" for v in args.attitude))
            else:
                motion, what = protractor_profile(repeat=True), "protractor moves (1, 5, 10 deg about y and z)"
            source = ImuSimulator(motion, rate_hz=rate, faults=faults, seed=args.seed, timeline=timeline)
            what += f" at {rate:g} Hz"
        port = SimulatedPort(source, port_link=args.port_link, hold_s=args.hold,
                             on_start=None if epoch_file is None else lambda ns: _write_epoch(epoch_file, ns))
    except (ValueError, OSError) as err:
        raise UserError(str(err)) from None
    previous = signal.signal(signal.SIGTERM, _interrupt)      # `kill` cleans up like Ctrl-C
    if timeline is not None:
        threading.Thread(target=timeline.follow, args=(sys.stdin,), daemon=True).start()
    if args.parent is not None:
        threading.Thread(target=_stop_with_parent, args=(args.parent,), daemon=True).start()
    try:
        with port:
            link = f" (link {args.port_link})" if args.port_link else ""
            print(f"IMU simulator on {port.device}{link}: {what}; starts when a reader opens the port; "
                  "Ctrl-C to stop", flush=True)
            port.run()
    except KeyboardInterrupt:
        pass
    finally:
        signal.signal(signal.SIGTERM, previous)
    return 0


def _write_epoch(path, motion_start_ns: int) -> None:
    """The motion's start on the host clock, in ns, as one line (written whole: a reader never sees half of it)."""
    from snreg.files import atomic_write

    try:
        with atomic_write(path) as temporary:
            temporary.write_text(f"{motion_start_ns}\n")
    except OSError as err:
        raise UserError(f"cannot write the epoch file {path} ({err.strerror or err}); "
                        "choose a writable place") from None


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def _stop_with_parent(pid: int) -> None:
    """Interrupt the simulator once ``pid`` is no longer its parent (the app ended, even by SIGKILL)."""
    while os.getppid() == pid:
        time.sleep(0.5)
    os.kill(os.getpid(), signal.SIGTERM)      # a real signal: it also ends a write blocked on a pty nobody reads
