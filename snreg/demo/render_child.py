"""The render process of :class:`snreg.demo.render_process.TourRenderProcess`: ``python -m snreg.demo.render_child``.

On stdin, pickled: first ``(args, kwargs, within)``, the :class:`~snreg.demo.surgery_scene.SurgeryScene` to render
(made alike in both processes, so its frames are the app's own: the noise is seeded by each frame's key) and how many
frames ahead of the play to render, then ``("played", index)`` as the play moves on. On stdout, pickled: ``("rendered",
key, distinct frame)`` for each distinct frame in tour order from the play, each once. It ends once the tour is all
sent, or at the end of its stdin (the app closed it or is gone), so it never outlives the app.
"""

from __future__ import annotations

import os
import pickle
import sys
import threading

from snreg.demo.surgery_scene import SurgeryScene
from snreg.workflow.tracking_child import NICER

WAKE_S = 0.1        # with every near frame sent, how often it looks whether the play moved on


def main(argv: list[str]) -> int:
    if hasattr(os, "nice"):                     # POSIX; elsewhere the child runs at the app's priority
        os.nice(NICER)
    frames = os.fdopen(os.dup(1), "wb")         # the frames' own channel: a stray print goes to stderr
    os.dup2(2, 1)
    orders = sys.stdin.buffer
    try:
        args, kwargs, within = pickle.load(orders)
    except (EOFError, pickle.UnpicklingError):
        return 0
    scene = SurgeryScene(*args, **kwargs)
    played, moved, ended = [0], threading.Event(), threading.Event()

    def listen() -> None:
        try:
            while True:
                message = pickle.load(orders)
                if message[0] == "played":
                    played[0] = int(message[1])
                    moved.set()
        except (EOFError, OSError, pickle.UnpicklingError, ValueError):
            pass
        ended.set()
        moved.set()

    threading.Thread(target=listen, name="render-orders", daemon=True).start()
    sent: set[tuple[int, int]] = set()
    try:
        while not ended.is_set() and len(sent) < scene.distinct_frames:
            index = scene.pending(played[0], within, done=sent)
            if index is None:                   # every frame near the play sent: wait for it to move on
                moved.wait(WAKE_S)
                moved.clear()
                continue
            key = scene.distinct_key(index)
            frames.write(pickle.dumps(("rendered", key, scene.render_distinct(index)),
                                      protocol=pickle.HIGHEST_PROTOCOL))
            frames.flush()
            sent.add(key)
    except (BrokenPipeError, OSError):          # the app is gone
        pass
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
