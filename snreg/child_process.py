"""Ending a child process the app started (the video encoder, the tracking process, the demo's tour renderer, the IMU
simulator): each ends at the end of its standard input, so closing it is the polite stop, and a child that does not
end within its time is killed, so the app's shutdown never hangs on one."""

from __future__ import annotations

import contextlib
import subprocess

__all__ = ["end_child"]


def end_child(process: subprocess.Popen, wait_s: float) -> None:
    """Close ``process``'s stdin, wait up to ``wait_s`` for it to end, kill it if it has not; it is waited for either
    way (no zombie)."""
    if process.stdin is not None:
        with contextlib.suppress(OSError):
            process.stdin.close()
    try:
        process.wait(wait_s)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()
