"""``snreg``: the command line (DESIGN.md §4). Errors a user can cause: one line on stderr, exit 2."""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

import numpy as np

from snreg import __version__
from snreg.errors import UserError

EXIT_BAD_INPUT = 2


def _floats(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None


def _ints(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None


def _read_initial(path: str | None) -> np.ndarray | None:
    if path is None:
        return None
    try:
        text = Path(path).read_text(encoding="utf-8")
        data = json.loads(text) if path.endswith(".json") else np.loadtxt(path, delimiter=None if "," not in text else ",")
        matrix = np.asarray(data.get("transform", data) if isinstance(data, dict) else data, dtype=float)
    except (OSError, ValueError) as err:
        raise UserError(f"{path}: cannot read a 4x4 initial transform ({err})") from None
    if matrix.shape != (4, 4):
        raise UserError(f"{path}: the initial transform must be 4x4, got shape {matrix.shape}")
    return matrix


def cmd_register(args) -> int:
    from snreg.nodes import NodeFileError, read_nodes
    from snreg.registration import CONFIDENT, register
    from snreg.session import read_intraop_nodes

    try:
        preop = read_nodes(args.preop)
        is_session = Path(args.intraop).suffix.lower() in (".h5", ".hdf5")
        intraop = read_intraop_nodes(args.intraop) if is_session else read_nodes(args.intraop)
    except (NodeFileError, ValueError) as err:
        raise UserError(str(err)) from None
    try:
        result = register(preop.xyz, intraop.xyz, method=args.method,
                          preop_labels=preop.labels if args.labels else None,
                          intraop_labels=intraop.labels if args.labels else None,
                          initial=_read_initial(args.initial), max_rotation_deg=args.max_rotation,
                          max_translation_mm=args.max_translation, seed=args.seed)
    except ValueError as err:
        raise UserError(str(err)) from None
    nodes = []
    for m in range(len(intraop)):
        n = int(result.pairing[m])
        nodes.append({"id": intraop.ids[m], "label": intraop.labels[m],
                      "preop_id": preop.ids[n] if n >= 0 else None, "preop_label": preop.labels[n] if n >= 0 else None,
                      "distance_mm": round(float(result.distances_mm[m]), 3),
                      "confidence": round(float(result.confidence[m]), 4),
                      "confident": bool(result.confidence[m] >= CONFIDENT)})
    doc = {"method": result.method, "pairing_rule": result.pairing_rule, "rms_mm": result.rms_mm,
           "confident_threshold": CONFIDENT, "intraop_from_preop": result.transform.tolist(), "nodes": nodes}
    if args.output:
        Path(args.output).write_text(json.dumps(doc, indent=2), encoding="utf-8")
    if args.json:
        print(json.dumps(doc))
        return 0
    print(f"method {result.method}, RMS {result.rms_mm:.2f} mm, pairing rule {result.pairing_rule}")
    print(f"{'intraop':<10} {'label':<10} {'preop':<10} {'label':<10} {'dist mm':>8} {'conf':>6}")
    for node in nodes:
        mark = "" if node["confident"] else "  (check)"
        print(f"{node['id']:<10} {node['label']:<10} {node['preop_id'] or 'extra':<10} {node['preop_label'] or '':<10} "
              f"{node['distance_mm']:>8.1f} {node['confidence']:>6.2f}{mark}")
    return 0


def cmd_simulate(args) -> int:
    from snreg.simulation import StudyConfig, load_cohort, run_study, synthetic_cohort, write_report
    from snreg.simulation.report import table6
    from snreg.simulation.study import parse_method

    try:
        for spec in args.methods:
            parse_method(spec)
        patients = load_cohort(args.cohort) if args.cohort else synthetic_cohort()
    except ValueError as err:
        raise UserError(str(err)) from None
    if args.reps < 1 or not args.sigmas or not args.extras or min(args.extras) < 0:
        raise UserError("--reps must be >= 1, --sigmas and --extras non-empty and extras >= 0")
    config = StudyConfig(methods=tuple(args.methods), sigmas=args.sigmas, extras=args.extras, reps=args.reps,
                         seed=args.seed, workers=args.workers)
    study = run_study(patients, config, progress=not args.quiet)
    command = "snreg " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    paths = write_report(study, args.output, command)
    print(table6(study))
    print(f"\nreport: {paths['markdown']}  trials: {paths['trials']}", file=sys.stderr)
    return 0


def cmd_track(args) -> int:
    import cv2

    from snreg.camera import CalibrationFileError, load_calibration
    from snreg.probe import load_probe_model
    from snreg.tracking import StereoTracker, TrackingError

    try:
        calibration = load_calibration(args.calib)
        probe = load_probe_model(args.probe)
    except (CalibrationFileError, ValueError) as err:
        raise UserError(str(err)) from None
    images = []
    for path in (args.left, args.right):
        image = cv2.imread(path, cv2.IMREAD_COLOR)
        if image is None:
            raise UserError(f"{path}: not a readable image")
        images.append(image)
    tracker = StereoTracker(calibration, probe, method=args.method)
    try:
        fix = tracker.marker_width(images[0]) if args.method == "width" else tracker.track(*images)
    except TrackingError as err:
        raise UserError(f"{err}") from None
    doc = fix.as_dict()
    if args.json:
        print(json.dumps(doc))
    else:
        print(f"tip    {fix.tip[0]:8.2f} {fix.tip[1]:8.2f} {fix.tip[2]:8.2f} mm (camera frame)")
        print(f"centre {fix.centre[0]:8.2f} {fix.centre[1]:8.2f} {fix.centre[2]:8.2f} mm")
        print(f"axis   {fix.axis[0]:8.4f} {fix.axis[1]:8.4f} {fix.axis[2]:8.4f}")
        print(f"quality {fix.quality:.3f} ({fix.n_stripes} stripes, {fix.method})")
    return 0


def cmd_experiment_tracking(args) -> int:
    from snreg.camera import thesis_calibration
    from snreg.probe import default_probe_model
    from snreg.simulation.tracking import THESIS_BANDS, format_table, run_tracking_experiment

    if args.frames < 2:
        raise UserError("--frames must be at least 2")

    def progress(done, total):
        print(f"\rtracking experiment: {done}/{total} positions", end="" if done < total else "\n",
              file=sys.stderr, flush=True)

    results = run_tracking_experiment(thesis_calibration(), default_probe_model(), THESIS_BANDS, frames=args.frames,
                                      noise_sigma=args.noise, seed=args.seed, progress=progress)
    print(format_table(results))
    return 0


def cmd_experiment_imu(args) -> int:
    from snreg.simulation.imu import format_table, measure_yaw_drift, run_protractor_experiment

    print(format_table(run_protractor_experiment(seed=args.seed)))
    with_bias = measure_yaw_drift(seed=args.seed)
    without = measure_yaw_drift(seed=args.seed, bias_correction=False)
    print(f"\nyaw drift of a still sensor (no magnetometer), z gyro bias {with_bias.bias_dps[2]:+.3f} deg/s: "
          f"{with_bias.deg_per_min:+.3f} deg/min with bias correction, "
          f"{without.deg_per_min:+.3f} deg/min without")
    return 0


def cmd_bench(args) -> int:
    from snreg.simulation.bench import bench_registration, bench_tracking, format_rows, format_tracking

    print("registration (simulated cases, one process):")
    print(format_rows(bench_registration(reps=args.reps, compare=args.compare)))
    print("\ntracking (rendered 1920x1080 pairs, one process):")
    print(format_tracking(bench_tracking(pairs=args.pairs)))
    return 0


def build_parser() -> argparse.ArgumentParser:
    from snreg.calibration.command import add_calibrate_parser
    from snreg.calibration.trocar_command import add_trocar_parser
    from snreg.demo.command import add_demo_parser
    from snreg.imu.command import add_imu_parser
    from snreg.preop.command import add_preop_parser
    from snreg.registration import METHODS
    from snreg.session.command import add_session_parser
    from snreg.simulation.study import DEFAULT_EXTRAS, DEFAULT_METHODS, DEFAULT_REPS, DEFAULT_SIGMAS

    parser = argparse.ArgumentParser(prog="snreg", description="Sentinel-node registration tools.")
    parser.add_argument("--version", action="version", version=f"snreg {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("register", help="register preop nodes to intraop nodes and pair them")
    p.add_argument("preop", help="preop node file (.csv or .mrk.json)")
    p.add_argument("intraop", help="intraop node file (.csv or .mrk.json) or session (.h5)")
    p.add_argument("--method", choices=METHODS, default="global")
    p.add_argument("--labels", action="store_true", help="use the anatomical labels (e.g. 'OBT R')")
    p.add_argument("--initial", help="rough intraop_from_preop: 4x4 text or JSON file")
    p.add_argument("--max-rotation", type=float, default=60.0, help="degrees (default 60)")
    p.add_argument("--max-translation", type=float, default=60.0, help="mm (default 60)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("-o", "--output", help="write the result as JSON")
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")
    p.set_defaults(func=cmd_register)

    p = sub.add_parser("simulate", help="the thesis' registration simulation study on a cohort")
    p.add_argument("--reps", type=int, default=DEFAULT_REPS, help="repetitions per patient, sigma and extras")
    p.add_argument("--sigmas", type=_floats, default=DEFAULT_SIGMAS, help="intraop error sigma per axis, mm")
    p.add_argument("--extras", type=_ints, default=DEFAULT_EXTRAS, help="numbers of extra intraop nodes")
    p.add_argument("--methods", type=lambda s: tuple(s.split(";") if ";" in s else s.split(",")),
                   default=DEFAULT_METHODS, help="e.g. icp,cpd,chamfer,global,global+labels (';' to separate specs with options)")
    p.add_argument("--cohort", help="directory of preop node CSVs, one per patient (default: synthetic cohort)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=0, help="processes (default: one per core)")
    p.add_argument("-o", "--output", default="snreg-simulation", help="report directory")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")
    p.set_defaults(func=cmd_simulate)

    add_trocar_parser(add_calibrate_parser(sub))
    add_imu_parser(sub)
    add_preop_parser(sub)
    add_session_parser(sub)
    add_demo_parser(sub)

    p = sub.add_parser("track", help="probe position from one stereo pair")
    p.add_argument("left")
    p.add_argument("right")
    p.add_argument("--calib", required=True, help="stereo calibration file (.yaml)")
    p.add_argument("--probe", help="probe model file (default: resources/probe/drop_in_probe.yaml)")
    p.add_argument("--method", choices=("triangulation", "sgbm", "width"), default="triangulation")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_track)

    p = sub.add_parser("experiment", help="accuracy experiments")
    experiments = p.add_subparsers(dest="experiment", required=True)
    e = experiments.add_parser("tracking", help="thesis Table 4 on rendered frames")
    e.add_argument("--frames", type=int, default=60, help="noisy frames per probe position (thesis: 60)")
    e.add_argument("--noise", type=float, default=3.0, help="sensor noise sigma, grey levels")
    e.add_argument("--seed", type=int, default=0)
    e.set_defaults(func=cmd_experiment_tracking)
    e = experiments.add_parser("imu", help="thesis Fig. 19: simulated protractor rotations")
    e.add_argument("--seed", type=int, default=0)
    e.set_defaults(func=cmd_experiment_imu)

    p = sub.add_parser("bench", help="time the registration methods and the tracker")
    p.add_argument("--reps", type=int, default=2, help="cases per patient and extras count")
    p.add_argument("--compare", action="store_true", help="also probreg CPD and Open3D ICP where installed")
    p.add_argument("--pairs", type=int, default=40, help="stereo pairs to track")
    p.set_defaults(func=cmd_bench)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except UserError as err:
        print(f"snreg: {err}", file=sys.stderr)
        return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
