"""The tracking process of :class:`snreg.workflow.tracking_process.TrackingProcess`: ``python -m
snreg.workflow.tracking_child SHARED_MEMORY``.

On stdin, pickled: first (calibration, probe model, insertion tracker or None, slot shape), then ``("pair", SLOT,
left, right, earth_from_imu)`` (the images in that slot of the shared memory when SLOT >= 0, else in the message) and
at last ``("stop",)``. On stdout, pickled: ``("ready",)``, then per pair ``("tracked", TrackedPair)`` or ``("error",
exception)``, and at stop ``("kept", insertion tracker)``. At the end of stdin (the app is gone) it ends.
"""

from __future__ import annotations

import os
import pickle
import sys
from multiprocessing import resource_tracker, shared_memory

import numpy as np

from snreg.tracking import StereoTracker
from snreg.workflow.pair_tracking import track_pair

NICER = 5           # below the app's threads: the GUI thread gets a core first, tracking the CPU left


def main(argv: list[str]) -> int:
    if hasattr(os, "nice"):                     # POSIX; elsewhere the child runs at the app's priority
        os.nice(NICER)
    answers = os.fdopen(os.dup(1), "wb")        # the answers' own channel: a stray print goes to stderr
    os.dup2(2, 1)
    memory = shared_memory.SharedMemory(name=argv[0])
    resource_tracker.unregister(memory._name, "shared_memory")     # the parent owns it and unlinks it
    orders = sys.stdin.buffer

    def say(message) -> None:
        answers.write(pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL))
        answers.flush()
    try:
        calibration, probe, insertion, shape = pickle.load(orders)
        tracker = StereoTracker(calibration, probe)
        pair_bytes = int(np.prod(shape))
        say(("ready",))
        while True:
            message = pickle.load(orders)
            if message[0] == "stop":
                say(("kept", insertion))
                break
            _, slot, left, right, earth_from_imu = message
            if slot >= 0:           # copied out: the insertion tracker may keep a pair as a keyframe
                view = np.ndarray(shape, np.uint8, memory.buf, slot * pair_bytes)
                left, right = view[0].copy(), view[1].copy()
                del view
            try:
                say(("tracked", track_pair(tracker, insertion, left, right, earth_from_imu)))
            except Exception as err:             # raised in the parent, where tracking in its thread would raise it
                say(("error", err))
    except (EOFError, BrokenPipeError):
        pass
    finally:
        memory.close()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
