"""Run the simulation study: every patient x sigma x extras x repetition, every method, in parallel.

A method spec is ``name[+labels][:key=value,...]``: ``global+labels`` is given the station
labels (an extra node takes the label of the node it sits beside); ``cpd:w=0.1`` or
``chamfer:form=volume`` pass options to the solver.
"""

from __future__ import annotations

import os
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass

import numpy as np

from snreg.simulation.cohort import Patient
from snreg.simulation.protocol import error_stats, make_trial, oracle_success, run_trial

__all__ = ["parse_method", "StudyConfig", "StudyResult", "run_study", "DEFAULT_METHODS", "DEFAULT_SIGMAS", "DEFAULT_EXTRAS"]

DEFAULT_METHODS = ("icp", "cpd", "chamfer", "global")
DEFAULT_SIGMAS = (2.0, 5.0, 10.0, 15.0, 20.0)
DEFAULT_EXTRAS = (0, 1, 2, 3)
DEFAULT_REPS = 25


@dataclass(frozen=True)
class StudyConfig:
    methods: tuple[str, ...] = DEFAULT_METHODS
    sigmas: tuple[float, ...] = DEFAULT_SIGMAS
    extras: tuple[int, ...] = DEFAULT_EXTRAS
    reps: int = DEFAULT_REPS
    seed: int = 0
    workers: int = 0            # 0: one per core


@dataclass
class StudyResult:
    config: StudyConfig
    rows: list[dict]                                   # one per trial and method
    confidence: dict[str, np.ndarray]                  # method -> per-node confidence (true nodes)
    correct: dict[str, np.ndarray]                     # method -> per-node correctness


def parse_method(spec: str) -> tuple[str, bool, dict]:
    """(method, use_labels, solver options) from a spec such as ``cpd:w=0.1`` or ``global+labels``."""
    head, _, tail = spec.partition(":")
    name, _, flag = head.partition("+")
    if flag not in ("", "labels"):
        raise ValueError(f"method spec {spec!r}: only '+labels' may follow the method name")
    options = {}
    for item in filter(None, tail.split(",")):
        key, sep, value = item.partition("=")
        if not sep:
            raise ValueError(f"method spec {spec!r}: options are key=value")
        try:
            options[key] = float(value)
        except ValueError:
            options[key] = value
    return name, flag == "labels", options


def _run_block(patient: Patient, patient_index: int, sigma_index: int, config: StudyConfig):
    rows, conf, corr = [], {m: [] for m in config.methods}, {m: [] for m in config.methods}
    sigma = config.sigmas[sigma_index]
    for n_extra in config.extras:
        for rep in range(config.reps):
            trial = make_trial(patient.name, patient.nodes.xyz, patient.nodes.labels, sigma, n_extra, rep,
                               (config.seed, patient_index, sigma_index, n_extra, rep))
            common = {"patient": patient.name, "n_nodes": len(patient.nodes), "sigma": sigma,
                      "n_extra": n_extra, "rep": rep, **oracle_success(trial), **error_stats(trial)}
            for method in config.methods:
                base, use_labels, options = parse_method(method)
                outcome = run_trial(trial, base, use_labels=use_labels, **options)
                rows.append({**common, "method": method, **outcome.row})
                conf[method].append(outcome.confidence)
                corr[method].append(outcome.correct)
    return rows, conf, corr


def run_study(patients: list[Patient], config: StudyConfig, progress=True) -> StudyResult:
    """All trials of the study; deterministic under ``config.seed`` whatever the worker count."""
    blocks = [(p, k, s) for k, p in enumerate(patients) for s in range(len(config.sigmas))]
    workers = config.workers or os.cpu_count() or 1
    results = [None] * len(blocks)
    if workers == 1:
        for i, (p, k, s) in enumerate(blocks):
            results[i] = _run_block(p, k, s, config)
            _progress(progress, i + 1, len(blocks))
    else:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            futures = {pool.submit(_run_block, p, k, s, config): i for i, (p, k, s) in enumerate(blocks)}
            for done, future in enumerate(as_completed(futures), start=1):
                results[futures[future]] = future.result()
                _progress(progress, done, len(blocks))
    rows = [row for block in results for row in block[0]]
    confidence = {m: np.concatenate([c for block in results for c in block[1][m]]) for m in config.methods}
    correct = {m: np.concatenate([c for block in results for c in block[2][m]]) for m in config.methods}
    return StudyResult(config, rows, confidence, correct)


def _progress(enabled: bool, done: int, total: int) -> None:
    if enabled:
        print(f"\rsimulate: {done}/{total} patient x sigma blocks", end="" if done < total else "\n",
              file=sys.stderr, flush=True)
