"""Run the simulation study: every patient x sigma x missing x extras x repetition, every method, in parallel.

A method spec is ``name[+labels][+cov][+landmarks][:key=value,...]``: ``global+labels`` is given the station
labels (an extra node takes the label of the node it sits beside), ``global+cov`` each node's error
covariance, ``global+landmarks`` the anatomical landmarks; ``cpd:w=0.1`` or ``chamfer:form=volume`` pass options
to the solver.
"""

from __future__ import annotations

import os
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field, replace

import numpy as np

from snreg.registration import register
from snreg.simulation.cohort import Patient
from snreg.simulation.landmarks import with_landmarks
from snreg.simulation.protocol import Trial, error_stats, make_trial, oracle_success, run_trial
from snreg.simulation.workers import end_with_parent, worker_count

__all__ = ["parse_method", "check_method", "StudyConfig", "StudyResult", "run_study", "DEFAULT_METHODS", "DEFAULT_SIGMAS", "DEFAULT_EXTRAS"]

DEFAULT_METHODS = ("icp", "cpd", "chamfer", "global")
DEFAULT_SIGMAS = (2.0, 5.0, 10.0, 15.0, 20.0)
DEFAULT_EXTRAS = (0, 1, 2, 3)
DEFAULT_REPS = 25
_FLAGS = ("labels", "cov", "landmarks")


@dataclass(frozen=True)
class StudyConfig:
    methods: tuple[str, ...] = DEFAULT_METHODS
    sigmas: tuple[float, ...] = DEFAULT_SIGMAS
    extras: tuple[int, ...] = DEFAULT_EXTRAS
    reps: int = DEFAULT_REPS
    seed: int = 0
    workers: int = 0            # 0: one per core; never more than the cores
    missing: tuple[int, ...] = (0,)   # true intraop nodes left out (0: the thesis protocol)
    anisotropy: float = 1.0     # error along each node's viewing ray over across it (1: the thesis protocol)
    landmarks: int = 0          # anatomical landmark pairs per trial (issue 29)
    landmark_sd: float = 2.0    # their own error, mm per axis
    max_nodes: int | None = None   # patients cut down to this many SPECT nodes
    swap_landmarks: bool = False   # the first two landmarks' names exchanged on the intraop side
    start: str = "rough"        # "rough": the thesis' rough alignment; "gravity": any turn and shift, the downs given
    tilt_sd_deg: float = 8.0    # gravity start: error of the entered table tilt
    imu_down_sd_deg: float = 1.0   # gravity start: error of the IMU's down

    @property
    def incremental(self) -> bool:
        """The incremental scenario runs with a study of missing nodes (never in the thesis protocol alone)."""
        return any(k > 0 for k in self.missing)


@dataclass
class StudyResult:
    """Trial rows (one per trial and method) and, per method, node-level arrays: ``confidence``/``correct`` of the
    true intraop nodes; ``claims`` (every intraop node's claim: confidence, correct, sigma, n_missing, extra);
    ``bounds`` (every left-out preop node: bound_mm, error_mm, sigma); ``incremental`` rows (one per registration of
    the incremental scenario)."""

    config: StudyConfig
    rows: list[dict]
    confidence: dict[str, np.ndarray]
    correct: dict[str, np.ndarray]
    claims: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    bounds: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    incremental: list[dict] = field(default_factory=list)


def parse_method(spec: str) -> tuple[str, dict]:
    """(method, keywords for :func:`~snreg.simulation.protocol.run_trial`: ``use_labels``, ``use_cov`` and the solver
    options) from a spec such as ``cpd:w=0.1``, ``global+labels`` or ``global+labels+cov``."""
    head, _, tail = spec.partition(":")
    name, *flags = head.split("+")
    if any(flag not in _FLAGS for flag in flags) or len(set(flags)) < len(flags):
        raise ValueError(f"method spec {spec!r}: only {', '.join('+' + f for f in _FLAGS)} may follow the method name")
    options: dict = {f"use_{flag}": flag in flags for flag in _FLAGS}
    for item in filter(None, tail.split(",")):
        key, sep, value = item.partition("=")
        if not sep:
            raise ValueError(f"method spec {spec!r}: options are key=value")
        try:
            options[key] = float(value)
        except ValueError:
            options[key] = value
    return name, options


def check_method(spec: str) -> None:
    """Raise ``ValueError`` naming ``spec`` when it is not a method spec :func:`register` accepts (unknown method
    or option, an option value out of range): one tiny registration, so a study never fails after its first hour."""
    name, options = parse_method(spec)
    solver = {key: value for key, value in options.items() if not key.startswith("use_")}
    tetrahedron = np.array([[0.0, 0.0, 0.0], [40.0, 0.0, 0.0], [0.0, 30.0, 0.0], [10.0, 10.0, 25.0]])
    try:
        register(tetrahedron, tetrahedron + 1.0, method=name, **solver)
    except (ValueError, TypeError) as err:
        raise ValueError(f"method spec {spec!r}: {err}") from None


class _Collected:
    """What one block of trials gives, per method."""

    def __init__(self, methods):
        self.rows: list[dict] = []
        self.nodes = {m: {k: [] for k in ("confidence", "correct")} for m in methods}
        self.claims = {m: {k: [] for k in ("confidence", "correct", "sigma", "n_missing", "extra")} for m in methods}
        self.bounds = {m: {k: [] for k in ("bound_mm", "error_mm", "sigma")} for m in methods}
        self.incremental: list[dict] = []

    def add(self, trial: Trial, method: str, outcome, common: dict) -> None:
        self.rows.append({**common, "method": method, **outcome.row})
        self.nodes[method]["confidence"].append(outcome.confidence)
        self.nodes[method]["correct"].append(outcome.correct)
        claims = self.claims[method]
        claims["confidence"].append(outcome.claim_confidence)
        claims["correct"].append(outcome.claim_correct)
        claims["sigma"].append(np.full(len(trial.truth), trial.sigma))
        claims["n_missing"].append(np.full(len(trial.truth), trial.n_missing))
        claims["extra"].append(trial.truth < 0)
        bounds = self.bounds[method]
        bounds["bound_mm"].append(outcome.bound_mm)
        bounds["error_mm"].append(outcome.left_out_error_mm)
        bounds["sigma"].append(np.full(len(outcome.bound_mm), trial.sigma))


def _trial(patient: Patient, patient_index: int, sigma_index: int, n_extra: int, rep: int, config: StudyConfig,
           n_missing: int = 0) -> Trial:
    words = (config.seed, patient_index, sigma_index, n_extra, rep)
    keep = slice(None) if config.max_nodes is None else slice(0, config.max_nodes)
    trial = make_trial(patient.name, patient.nodes.xyz[keep], patient.nodes.labels[keep], config.sigmas[sigma_index],
                       n_extra, rep, words, n_missing=n_missing, anisotropy=config.anisotropy,
                       min_true=1 if config.landmarks else 3, start=config.start, tilt_sd_deg=config.tilt_sd_deg,
                       imu_down_sd_deg=config.imu_down_sd_deg)
    if config.landmarks:
        rng = np.random.default_rng(np.random.SeedSequence(words + (29,)))
        trial = with_landmarks(trial, config.landmarks, config.landmark_sd, rng, config.swap_landmarks)
    return trial


def _run_block(patient: Patient, patient_index: int, sigma_index: int, config: StudyConfig) -> _Collected:
    out = _Collected(config.methods)
    for n_missing in config.missing:
        nodes = len(patient.nodes) if config.max_nodes is None else min(len(patient.nodes), config.max_nodes)
        if nodes - n_missing < (1 if config.landmarks else 3):
            continue                                   # at least 3 true nodes remain (1 beside landmarks)
        for n_extra in config.extras:
            for rep in range(config.reps):
                trial = _trial(patient, patient_index, sigma_index, n_extra, rep, config, n_missing)
                common = {"patient": patient.name, "n_nodes": len(patient.nodes), "sigma": trial.sigma,
                          "n_missing": n_missing, "n_extra": n_extra, "rep": rep, **oracle_success(trial),
                          **error_stats(trial)}
                for method in config.methods:
                    base, options = parse_method(method)
                    out.add(trial, method, run_trial(trial, base, **options), common)
    if config.incremental:
        out.incremental = _incremental(patient, patient_index, sigma_index, config)
    return out


def _incremental(patient: Patient, patient_index: int, sigma_index: int, config: StudyConfig) -> list[dict]:
    """Nodes stored one by one in a random order (the trial's shuffled order), registering after each store from the
    third on: per registration, whether every stored true node and every stored node's claim was right."""
    rows = []
    for rep in range(config.reps):
        n_extra = config.extras[rep % len(config.extras)]
        trial = _trial(patient, patient_index, sigma_index, n_extra, rep, config)
        for stored in range(3, len(trial.intraop) + 1):
            part = replace(trial, intraop=trial.intraop[:stored], truth=trial.truth[:stored],
                           intraop_labels=trial.intraop_labels[:stored], source=trial.source[:stored],
                           intraop_cov=trial.intraop_cov[:stored], n_missing=0, left_out=np.zeros(0, dtype=int),
                           left_out_xyz=np.zeros((0, 3)))
            true_stored = int(np.sum(part.truth >= 0))
            for method in config.methods:
                base, options = parse_method(method)
                outcome = run_trial(part, base, **options)
                rows.append({"patient": patient.name, "sigma": trial.sigma, "rep": rep, "method": method,
                             "stored": stored, "true_stored": true_stored, "n_nodes": len(patient.nodes),
                             "success": outcome.row["success"], "all_claims_right": bool(outcome.claim_correct.all())})
    return rows


def run_study(patients: list[Patient], config: StudyConfig, progress=True) -> StudyResult:
    """All trials of the study; deterministic under ``config.seed`` whatever the worker count."""
    blocks = [(p, k, s) for k, p in enumerate(patients) for s in range(len(config.sigmas))]
    workers = worker_count(config.workers)
    results: list[_Collected | None] = [None] * len(blocks)
    if workers == 1:
        for i, (p, k, s) in enumerate(blocks):
            results[i] = _run_block(p, k, s, config)
            _progress(progress, i + 1, len(blocks))
    else:
        with ProcessPoolExecutor(max_workers=workers, initializer=end_with_parent, initargs=(os.getpid(),)) as pool:
            futures = {pool.submit(_run_block, p, k, s, config): i for i, (p, k, s) in enumerate(blocks)}
            for done, future in enumerate(as_completed(futures), start=1):
                results[futures[future]] = future.result()
                _progress(progress, done, len(blocks))
    rows = [row for block in results for row in block.rows]

    def joined(part: str, method: str, key: str) -> np.ndarray:
        arrays = [a for block in results for a in getattr(block, part)[method][key]]
        return np.concatenate(arrays) if arrays else np.zeros(0)

    methods = config.methods
    confidence = {m: joined("nodes", m, "confidence") for m in methods}
    correct = {m: joined("nodes", m, "correct").astype(bool) for m in methods}
    claims = {m: {k: joined("claims", m, k) for k in ("confidence", "correct", "sigma", "n_missing", "extra")}
              for m in methods}
    for m in methods:
        claims[m]["correct"], claims[m]["extra"] = claims[m]["correct"].astype(bool), claims[m]["extra"].astype(bool)
    bounds = {m: {k: joined("bounds", m, k) for k in ("bound_mm", "error_mm", "sigma")} for m in methods}
    incremental = [row for block in results for row in block.incremental]
    return StudyResult(config, rows, confidence, correct, claims, bounds, incremental)


def _progress(enabled: bool, done: int, total: int) -> None:
    if enabled:
        print(f"\rsimulate: {done}/{total} patient x sigma blocks", end="" if done < total else "\n",
              file=sys.stderr, flush=True)
