"""The surgery tour rendered ahead of the play in a process of its own (issue 36).

Why: rendering the tour's distinct frames is numpy-heavy Python (~25 s of CPU a tour, 0.1 s a frame), and in a thread
of the app's process it held the GIL the GUI thread and the acquisition wait for. In a child
(:mod:`snreg.demo.render_child`, :data:`~snreg.workflow.tracking_child.NICER` steps nicer than the app, so the GUI
and tracking get the cores first) only the frames' arrival costs the app: a listener thread unpickles each and hands
it to the app's scene (:meth:`~snreg.demo.surgery_scene.SurgeryScene.keep`). The feed still renders any frame not
there yet itself (:meth:`~snreg.demo.surgery_scene.SurgeryScene.render`), as with the renderer thread.

How, after :mod:`snreg.workflow.tracking_process`: ``python -m snreg.demo.render_child`` (no fork of a process that
runs Qt), told the scene to make and, as the play moves on, the frame played; the frames come back pickled over its
stdout. The child ends at the end of its stdin, so it never outlives the app; :meth:`TourRenderProcess.close` closes
it and kills the child if it does not end.
"""

from __future__ import annotations

import pickle
import subprocess
import sys
import threading

from snreg.child_process import end_child
from snreg.demo.surgery_scene import SurgeryScene

__all__ = ["TourRenderProcess"]

STOP_S = 5.0        # for the child to end once its stdin is closed (it finishes the frame it renders), then killed


class TourRenderProcess:
    """The distinct frames of ``scene`` (a :class:`~snreg.demo.surgery_scene.SurgeryScene` made of ``args`` and
    ``kwargs``) rendered in a child process up to ``within`` frames ahead of the frame :meth:`follow` was told, kept in
    ``scene`` as they come."""

    def __init__(self, scene: SurgeryScene, args: tuple, kwargs: dict, within: int):
        self._scene = scene
        self._played: int | None = None
        self._ended = threading.Event()
        self._process = subprocess.Popen([sys.executable, "-m", "snreg.demo.render_child"], stdin=subprocess.PIPE,
                                         stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
        self._send((args, kwargs, int(within)))
        self._listener = threading.Thread(target=self._listen, name="demo-tour-renderer-frames", daemon=True)
        self._listener.start()

    @property
    def pid(self) -> int:
        """The child's process id (its CPU time is the simulated camera's, not the app's)."""
        return self._process.pid

    @property
    def ended(self) -> bool:
        """The child ended (the tour all sent, or it died: :attr:`SurgeryScene.rendered` says which)."""
        return self._ended.is_set()

    def follow(self, played: int) -> None:
        """Tell the child the play is at frame ``played``: it renders from there on."""
        if played != self._played and not self.ended:
            self._played = played
            self._send(("played", int(played)))

    def close(self) -> None:
        """End the child (at once: its stdin closed, killed after :data:`STOP_S`) and its listener."""
        end_child(self._process, STOP_S)
        self._listener.join()

    def _send(self, message) -> None:
        try:
            self._process.stdin.write(pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL))
            self._process.stdin.flush()
        except (OSError, ValueError):           # the child ended: the feed renders what is missing
            pass

    def _listen(self) -> None:
        """Each frame the child sends into the scene, until its stdout closes."""
        try:
            while True:
                _, key, rendered = pickle.load(self._process.stdout)
                self._scene.keep(key, rendered)
        except (EOFError, OSError, pickle.UnpicklingError, ValueError):
            pass
        self._ended.set()
