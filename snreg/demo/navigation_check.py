"""Navigation checked against the truth over the headless demo's seeds: ``python -m snreg.demo.navigation_check``.

Why: issue 36's acceptance. Each run (``snreg demo --headless --json --errors thesis --camera still|surgery --seed
N``) logs, per processed frame, every hot spot not found yet against the phantom's truth (:mod:`snreg.demo.
navigation_log`); this runs them (two at a time: each renders and tracks) and prints the four figures:

- the share of a hot spot's approach frames (from the first registration that leaves it unfound to its store) in which
  it is shown (drawn as not found) with a confident pairing, pooled over the runs (goal: >= 80 %);
- the runs whose hot spots lie, at the last frame before their store, within ``bound_mm`` of their predicted position
  (goal: 10 of 12);
- the median ``bound_mm`` against the median distance truth - predicted (goal: at most 2.5 times);
- the median distance between the pixel drawn (estimated camera pose) and the prediction's pixel from the true pose, as
  a share of the image's width (goal: at most 1 %).

A run that fails (a node never held still within the demo's tours, a run past :data:`TIMEOUT_S`) is listed with its
message and left out of the figures.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from snreg.camera import thesis_calibration

__all__ = ["Figures", "figures", "run_demo", "main", "IMAGE_WIDTH_PX"]

IMAGE_WIDTH_PX = thesis_calibration().image_size[0] * 0.5      # the headless demo's cameras: half the thesis' 1920
TIMEOUT_S = 1500


@dataclass(frozen=True)
class Figures:
    """The four figures over the runs' ``"navigation"`` entries (module docstring)."""

    runs: int
    approach_frames: int
    shown_confident: float          # share of approach frames shown as confident
    on_screen: float                # share of approach frames with the hot spot on the left image (drawn there)
    within_bound_runs: int          # runs whose every hot spot lay within its bound at its last frame
    median_bound_mm: float
    median_error_mm: float
    median_pose_px: float           # |left_px - left_px_true_pose|, median over frames with both on screen
    image_width_px: float

    def lines(self) -> list[str]:
        ratio = self.median_bound_mm / self.median_error_mm if self.median_error_mm > 0 else float("inf")
        return [f"runs: {self.runs}; approach frames: {self.approach_frames}",
                f"shown as confident: {100 * self.shown_confident:.1f} % of approach frames (goal >= 80 %); on the "
                f"left image: {100 * self.on_screen:.1f} %",
                f"truth within bound_mm at the last frame before the store: {self.within_bound_runs} of {self.runs} "
                "runs (goal >= 10 of 12)",
                f"median bound_mm {self.median_bound_mm:.2f} mm, median |truth - predicted| {self.median_error_mm:.2f} mm:"
                f" {ratio:.2f} x (goal <= 2.5)",
                f"median |left_px - left_px_true_pose| {self.median_pose_px:.2f} px = "
                f"{100 * self.median_pose_px / self.image_width_px:.2f} % of the {self.image_width_px:.0f} px width "
                "(goal <= 1 %)"]


def figures(runs: list[list[dict]], image_width_px: float = IMAGE_WIDTH_PX) -> Figures:
    """:class:`Figures` of the ``"navigation"`` entry lists of completed runs."""
    entries = [e for run in runs for e in run]
    last = []
    within = 0
    for run in runs:
        final = {}
        for e in run:
            final[e["hot_spot"]] = e                 # entries come in frame order: the last one stays
        ends = list(final.values())
        last += ends
        within += bool(ends) and all(_distance(e) <= e["bound_mm"] for e in ends)
    pose = [np.hypot(*np.subtract(e["left_px"], e["left_px_true_pose"])) for e in entries
            if e["left_px"] is not None and e["left_px_true_pose"] is not None]
    share = (lambda hits: float(np.mean(hits)) if entries else float("nan"))
    return Figures(len(runs), len(entries), share([e["shown"] and e["confident"] for e in entries]),
                   share([e["shown"] and e["left_px"] is not None for e in entries]), within,
                   float(np.median([e["bound_mm"] for e in last])) if last else float("nan"),
                   float(np.median([_distance(e) for e in last])) if last else float("nan"),
                   float(np.median(pose)) if pose else float("nan"), float(image_width_px))


def _distance(entry: dict) -> float:
    return float(np.linalg.norm(np.subtract(entry["truth_trocar"], entry["predicted_trocar"])))


def run_demo(camera: str, seed: int, folder: Path, errors: str = "thesis", fps: float | None = None,
             fixes: int = 60) -> tuple[list | None, str]:
    """One headless demo run: (its navigation entries, "") or (None, why it failed). ``fps``: None runs the command
    (``snreg demo --headless ...``); a pace runs the same demo with its feed at that pace (:func:`~snreg.demo.headless.
    run_headless`'s ``fps``: on a loaded computer a slower feed leaves time to process its frames)."""
    session = folder / f"{camera}-{seed}.h5"
    command = ([sys.executable, "-m", "snreg.cli", "demo", "--headless", "-o", str(session), "--json", "--errors",
                errors, "--camera", camera, "--seed", str(seed)] if fps is None else
               [sys.executable, "-m", "snreg.demo.navigation_check", "--one", camera, str(seed), str(fps), str(session),
                errors, str(fixes)])
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        return None, f"timed out after {TIMEOUT_S} s"
    if done.returncode != 0:
        return None, (done.stderr.strip().splitlines() or [f"exit {done.returncode}"])[-1]
    return json.loads(done.stdout)["navigation"], ""


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", default="1,2,3,4,5,6")
    parser.add_argument("--cameras", default="still,surgery")
    parser.add_argument("--parallel", type=int, default=2)
    parser.add_argument("--keep", type=Path, help="write each run's entries here as <camera>-<seed>.json")
    parser.add_argument("--fps", type=float, help="run the demo's feed at this pace instead of its own (30)")
    parser.add_argument("--fixes", type=int, default=60, help="fixes per node with --fps (the demo's: 60)")
    parser.add_argument("--one", nargs=6, metavar=("CAMERA", "SEED", "FPS", "SESSION", "ERRORS", "FIXES"),
                        help=argparse.SUPPRESS)          # one run at a pace, its JSON on stdout (run_demo)
    args = parser.parse_args(argv)
    if args.one:
        return _one(*args.one)
    jobs = [(camera, int(seed)) for camera in args.cameras.split(",") for seed in args.seeds.split(",")]
    completed = []
    with tempfile.TemporaryDirectory(prefix="snreg-navigation-") as folder, \
            ThreadPoolExecutor(args.parallel) as pool:
        runs = {pool.submit(run_demo, camera, seed, Path(folder), fps=args.fps, fixes=args.fixes): (camera, seed)
                for camera, seed in jobs}
        for done in as_completed(runs):                  # each run said as it ends: a long check shows progress
            (camera, seed), (entries, problem) = runs[done], done.result()
            if entries is None:
                print(f"{camera} seed {seed}: FAILED: {problem}", flush=True)
                continue
            completed.append(entries)
            if args.keep is not None:
                args.keep.mkdir(parents=True, exist_ok=True)
                (args.keep / f"{camera}-{seed}.json").write_text(json.dumps(entries))
            one = figures([entries])
            print(f"{camera} seed {seed}: {one.approach_frames} approach frames, shown confident "
                  f"{100 * one.shown_confident:.0f} %, error {one.median_error_mm:.2f} mm, bound "
                  f"{one.median_bound_mm:.2f} mm, pose {one.median_pose_px:.2f} px", flush=True)
    if completed:
        print("\n".join(figures(completed).lines()))
    return 0 if completed else 1


def _one(camera: str, seed: str, fps: str, session: str, errors: str, fixes: str) -> int:
    """``--one``: run the headless demo at ``fps`` and print its JSON (as ``snreg demo --headless --json`` does)."""
    from snreg.demo.errors import load_error_model
    from snreg.demo.headless import DemoError, run_headless

    try:
        run = run_headless(session, seed=int(seed), errors=load_error_model(errors), camera=camera, fps=float(fps),
                           fixes_per_node=int(fixes))
    except DemoError as err:
        print(f"snreg: {err}", file=sys.stderr)
        return 2
    print(json.dumps(run.to_json()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
