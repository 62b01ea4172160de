"""``snreg bench``: median time per case of every registration method, and per stereo pair of the probe tracker and
of the insertion tracker."""

from __future__ import annotations

import sys

from snreg.cli.common import int_range

__all__ = ["add_bench_parser", "cmd_bench"]


def add_bench_parser(subparsers) -> None:
    p = subparsers.add_parser("bench", help="time the registration methods and the tracker",
                              description="Time every registration method on simulated cases (one process) and the "
                                          "tracker on rendered 1920x1080 stereo pairs.")
    p.add_argument("--reps", type=int_range(1, 1000), default=2, help="cases per patient and extras count")
    p.add_argument("--compare", action="store_true", help="also probreg CPD and Open3D ICP where installed")
    p.add_argument("--pairs", type=int_range(1, 10_000), default=40, help="stereo pairs to track")
    p.set_defaults(func=cmd_bench)


def cmd_bench(args) -> int:
    from snreg.simulation.bench import (bench_insertion, bench_registration, bench_tracking, format_insertion,
                                        format_rows, format_tracking, probe_frames)

    print("bench: timing the registration methods ...", file=sys.stderr, flush=True)
    rows = bench_registration(reps=args.reps, compare=args.compare)
    print("registration (simulated cases, one process):")
    print(format_rows(rows), flush=True)
    print(f"bench: rendering and tracking {args.pairs} stereo pairs ...", file=sys.stderr, flush=True)
    print("\ntracking (rendered 1920x1080 pairs, one process, OpenCV's threads, wall time):")
    rendered = probe_frames(args.pairs)
    print(format_tracking(bench_tracking(pairs=args.pairs, rendered=rendered)), flush=True)
    print(f"bench: rendering a surgery video of {args.pairs} pairs and timing the camera's insertion against the probe "
          "tracker ...", file=sys.stderr, flush=True)
    print("\ncamera insertion against the probe tracker (rendered 1920x1080 surgery video and probe renders, one core, "
          "CPU time, the trackers taking turns pair by pair, every round's pairs pooled):")
    print(format_insertion(bench_insertion(pairs=args.pairs, rendered=rendered)))
    return 0
