"""``snreg budget``: where the phantom's error comes from. A Monte Carlo over the phantom experiment under an error
model (:mod:`snreg.demo.errors`), every source alone, all together and all but one.

Why: the thesis' phantom ended at 8.9 +- 3.3 and 11.4 +- 1.6 mm RMS (§5.1, Fig. 16) while its parts measured far
better alone; a research engineer needs "if I could improve one thing, which?". Each repetition draws every source's
error once (:func:`snreg.demo.error_draws.draw_errors`: stereo calibration and tracking on rendered frames, the IMU
through the simulator and the fusion, the SPECT through the segmentation, the rest by their formulas), then for every
configuration composes the node sets through the chain (:func:`~snreg.demo.error_draws.compose`) and registers them
with :func:`snreg.registration.register` from the operator's rough alignment. The same draw serves every
configuration, so differences between configurations are the sources', not the dice's. The costly draws (rendered
tracking, the fused IMU session) come from seeded pools that the repetitions share; SPECTs are drawn per repetition.

Beside the simulation, Fitzpatrick and West's prediction: from the node error (FLE) and the node layout, the
target registration error (TRE) and the RMS (FRE) a least-squares rigid fit should give.

Each node also gets the covariance the rig would give it (:mod:`snreg.demo.error_covariance`, issue 28), and each hot
spot the segmentation's; ``coverage_90`` is the share of nodes whose actual intraop error (measured minus true, trocar
frame) lies inside their own 90 % ellipsoid. With ``covariances`` the registration is given both.
"""

from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field, replace

import numpy as np

from snreg.camera import thesis_calibration
from snreg.demo.error_covariance import intraop_covariances
from snreg.demo.error_draws import cohort_geometry, compose, draw_errors, fused_imu_errors, phantom_geometry
from snreg.demo.error_stages import spect_errors
from snreg.demo.errors import SOURCES, ErrorModel
from snreg.demo.phantom import rough_alignment
from snreg.errors import NoFitError
from snreg.geometry import apply
from snreg.probe import default_probe_model
from snreg.registration import register
from snreg.registration.target import rigid_fit_covariance
from snreg.simulation.budget_tracking import TrackingBench, TrackingDraw
from snreg.simulation.workers import end_with_parent, worker_count
from snreg.tracking.uncertainty import inside_ellipsoid

__all__ = ["BudgetConfig", "BudgetResult", "Figure", "run_budget", "configurations", "DEFAULT_REPS"]

DEFAULT_REPS = 100
# how each source's code path or formula is run (the closing note's list)
PATHS = {"calibration": "code: snreg.calibration.stereo on simulated corners, then the tracker",
         "tracking": "code: rendered 1080p frames tracked by snreg.tracking (+ formula: residual_mm)",
         "pointing": "formula", "imu": "code: IMU simulator + snreg.imu.Fusion (+ formula: turn_error_deg)",
         "chain": "code: snreg.chain with the erring distances (misalignment as a rotation)",
         "spect": "code: synthetic SPECT segmented by snreg.preop", "tissue": "formula",
         "camera": "code: snreg.chain at the turned pose (insertion: formula)"}


@dataclass(frozen=True)
class BudgetConfig:
    """Repetitions, registration method, seed; ``draws``/``imu_draws``: the pools of tracked and fused draws the
    repetitions share; ``workers``: processes (0: one per core); ``cohort``: patient-like node sets, repetition r
    meeting patient r mod P (their tracking and IMU errors are the phantom's draws, node k taking phantom node k mod
    4's of its side); ``covariances``: register with each node's covariance and each hot spot's (as the rig and the
    segmentation would give them) instead of without."""

    reps: int = DEFAULT_REPS
    method: str = "chamfer"
    seed: int = 0
    draws: int = 6
    imu_draws: int = 12
    workers: int = 0
    cohort: tuple = ()          # patients as (nodes (N, 3) LPS mm, labels); empty: the phantom
    covariances: bool = False


@dataclass(frozen=True)
class Figure:
    """One configuration over the repetitions: registration RMS (R,), node errors (R * N,), TRE (R * N,) mm, pairing
    right (R,), the length of the error all nodes share (R,: a shift the registration cannot see), whether each
    node's intraop error lies inside its own 90 % ellipsoid (R * N,: 1, 0, NaN where the configuration gives the node
    no intraop error and no covariance), refusals."""

    rms_mm: np.ndarray
    node_error_mm: np.ndarray
    tre_mm: np.ndarray
    paired: np.ndarray
    common_mm: np.ndarray
    covered: np.ndarray
    failed: int = 0

    def to_json(self) -> dict:
        def q(values):
            values = values[np.isfinite(values)]
            if not len(values):
                return {"median": None, "p90": None}
            return {"median": round(float(np.median(values)), 3), "p90": round(float(np.percentile(values, 90)), 3)}

        return {"rms_mm": q(self.rms_mm), "node_error_mm": q(self.node_error_mm),
                "pairing_success": round(float(np.mean(self.paired)), 4), "coverage_90": _rounded(self.coverage_90)}

    @property
    def coverage_90(self) -> float:
        """Share of nodes whose intraop error lies inside their own 90 % ellipsoid; NaN when no node has one."""
        known = self.covered[np.isfinite(self.covered)]
        return float(np.mean(known)) if len(known) else float("nan")

    @property
    def rms_median(self) -> float:
        finite = self.rms_mm[np.isfinite(self.rms_mm)]
        return float(np.median(finite)) if len(finite) else float("nan")


@dataclass(frozen=True)
class BudgetResult:
    """Figures per configuration ("all", "none", "alone:S", "all_but:S"), the prediction, and how it was made."""

    model: ErrorModel
    config: BudgetConfig
    figures: dict[str, Figure]
    fle_mm: float
    tre_predicted_mm: float
    fre_predicted_mm: float
    lost_frames: int = 0
    paths: dict[str, str] = field(default_factory=lambda: dict(PATHS))

    @property
    def sources(self) -> tuple[str, ...]:
        """The sources the model switches on (scale above 0)."""
        return tuple(s for s in SOURCES if self.model.on(s))

    @property
    def dominant(self) -> str:
        """The source whose removal lowers the median RMS most."""
        base = self.figures["all"].rms_median
        return max(self.sources, key=lambda s: base - self.figures[f"all_but:{s}"].rms_median, default="")

    @property
    def tre_mc_mm(self) -> float:
        tre = self.figures["all"].tre_mm
        return float(np.sqrt(np.nanmean(tre**2)))

    def to_json(self) -> dict:
        """The ``--json`` object (docs/design.md, Contracts): ``{"all", "alone", "all_but", "tre_predicted_mm", "dominant"}``."""
        return {"all": self.figures["all"].to_json(),
                "alone": {s: self.figures[f"alone:{s}"].to_json() for s in self.sources},
                "all_but": {s: self.figures[f"all_but:{s}"].to_json() for s in self.sources},
                "tre_predicted_mm": round(self.tre_predicted_mm, 3), "dominant": self.dominant}


def configurations(model: ErrorModel) -> dict[str, ErrorModel]:
    """Every configuration the budget registers: all, none, each switched-on source alone, and all but it."""
    on = [s for s in SOURCES if model.on(s)]
    out = {"all": model, "none": model.only([])}
    for source in on:
        out[f"alone:{source}"] = model.only([source])
        out[f"all_but:{source}"] = model.only([s for s in on if s != source])
    return out


def run_budget(model: ErrorModel, config: BudgetConfig = BudgetConfig(), progress=None) -> BudgetResult:
    """The Monte Carlo; ``progress(done, total)`` is called as draws and repetitions finish."""
    geometry = phantom_geometry(default_probe_model())
    workers = min(worker_count(config.workers), config.reps)
    needs_tracking = bool(model.on("tracking") or model.on("calibration"))
    n_draws = min(config.draws, config.reps) if needs_tracking else 0
    total = n_draws + config.reps
    done = [0]

    def tick(count=1):
        done[0] += count
        if progress:
            progress(done[0], total)

    seeds = [int(v) for v in np.random.default_rng([config.seed, 1]).integers(1 << 31, size=max(n_draws, 1))]
    pool = _map(_tracking_draw, [(model, s) for s in seeds[:n_draws]], workers, tick)
    imu_jobs = [(model, geometry, config.seed * 7919 + q) for q in range(config.imu_draws)]
    imu_pool = [e for e in _map(_imu_draw, imu_jobs, workers, lambda: None) if e is not None]
    jobs = [(model, config, geometry, r, pool, imu_pool) for r in range(config.reps)]
    rows = _map(_repetition, jobs, workers, tick)
    figures = {name: _figure([row[name] for row in rows]) for name in rows[0] if name != "layout"}
    fle, tre, fre = _prediction(figures["all"], [row["layout"] for row in rows])
    lost = sum(d.lost_frames for d in pool)
    return BudgetResult(model, config, figures, fle, tre, fre, lost)


def _map(function, jobs, workers: int, tick):
    """``function`` over ``jobs`` in order, in ``workers`` processes (in this one for 1)."""
    if workers == 1 or len(jobs) <= 1:
        out = []
        for job in jobs:
            out.append(function(job))
            tick()
        return out
    with ProcessPoolExecutor(max_workers=workers, initializer=end_with_parent, initargs=(os.getpid(),)) as executor:
        out = []
        for result in executor.map(function, jobs, chunksize=max(1, len(jobs) // (4 * workers))):
            out.append(result)
            tick()
        return out


_BENCH: dict = {}


def _tracking_draw(job) -> TrackingDraw:
    model, seed = job
    bench = _BENCH.get("bench")
    if bench is None:               # one set of renders per process
        bench = _BENCH["bench"] = TrackingBench(thesis_calibration(), default_probe_model(),
                                                phantom_geometry(default_probe_model()))
    return bench.draw(model, seed)


def _imu_draw(job) -> np.ndarray | None:
    """One fused session's errors (None: the model's IMU is off or perfect)."""
    model, geometry, seed = job
    return fused_imu_errors(model, geometry, seed)


def _repetition(job) -> dict:
    """Every configuration's outcome for repetition ``r``: one draw, composed and registered per configuration."""
    model, config, phantom, r, pool, imu_pool = job
    rng = np.random.default_rng([config.seed, 2, r])
    geometry, like = phantom, np.arange(phantom.n)
    if config.cohort:
        nodes, labels = config.cohort[r % len(config.cohort)]
        geometry = cohort_geometry(nodes, labels, phantom, model["camera", "turn_deg"])
        like = _phantom_node_like(geometry, phantom)
    tracked = pool[r % len(pool)] if pool else None
    draw = draw_errors(model, geometry, rng, calibration=None if tracked is None else tracked.calibration[like],
                       tracking=None if tracked is None else tracked.tracking[like],
                       imu=imu_pool[r % len(imu_pool)][like] if imu_pool else None)
    full = compose(model, geometry, draw)
    spect = model.values["spect"]
    segmented = spect_errors(full.sources_lps, voxel_mm=spect["voxel_mm"], fwhm_mm=spect["fwhm_mm"],
                             peak_counts=spect["peak_counts"], seed=int(rng.integers(1 << 31)))
    draw = replace(draw, spect=segmented.offsets)
    cameras, probe = _rig()
    out = {}
    for name, variant in configurations(model).items():
        scenario = compose(variant, geometry, draw)
        covariances = (intraop_covariances(variant, scenario, cameras, probe, geometry.axis_camera),
                       variant.on("spect") ** 2 * segmented.covariances)
        out[name] = _outcome(scenario, covariances, config, r)
    out["layout"] = full.nodes_trocar
    return out


def _rig():
    """The calibration and probe the rig computes its nodes' covariances with (one per process)."""
    if "rig" not in _BENCH:
        _BENCH["rig"] = (thesis_calibration(), default_probe_model())
    return _BENCH["rig"]


def _phantom_node_like(geometry, phantom) -> np.ndarray:
    """(N,) per node of ``geometry`` the phantom node whose drawn errors it takes: one of the same side, in turn."""
    out = np.zeros(geometry.n, dtype=int)
    for pose in (0, 1):
        same = np.flatnonzero(phantom.poses == pose)
        mine = np.flatnonzero(geometry.poses == pose)
        out[mine] = same[np.arange(len(mine)) % len(same)]
    return out


def _outcome(scenario, covariances: tuple, config: BudgetConfig, r: int) -> tuple:
    """(rms, node errors (N,), TRE at the nodes (N,), pairing right?, common error, covered (N,)) of one registration,
    given the intraop and preop covariances (N, 3, 3) (used when ``config.covariances``); NaNs when it refused."""
    vectors = scenario.node_errors
    errors, common = np.linalg.norm(vectors, axis=1), float(np.linalg.norm(vectors.mean(axis=0)))
    covered = _covered(scenario.intraop - scenario.nodes_trocar, covariances[0])
    given = dict(intraop_cov=covariances[0], preop_cov=covariances[1]) if config.covariances else {}
    try:
        result = register(scenario.preop, scenario.intraop, method=config.method,
                          preop_labels=scenario.preop_labels, intraop_labels=scenario.intraop_labels,
                          initial=rough_alignment(scenario.preop, scenario.intraop), seed=config.seed + r, **given)
    except (NoFitError, ValueError):
        return float("nan"), errors, np.full(len(errors), np.nan), False, common, covered
    truth = apply(scenario.trocar_from_patient, scenario.sources_lps)
    tre = np.linalg.norm(apply(result.transform, scenario.sources_lps) - truth, axis=1)
    paired = bool(np.array_equal(result.pairing, np.arange(len(scenario.intraop))))
    return float(result.rms_mm), errors, tre, paired, common, covered


def _covered(offsets: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """(N,) 1.0 where a node's intraop error (N, 3) lies inside its 90 % ellipsoid, 0.0 where not, NaN where the
    covariance is singular (a configuration without any intraop error source)."""
    out = np.full(len(offsets), np.nan)
    regular = np.linalg.eigvalsh(covariances)[:, 0] > 1e-9
    out[regular] = inside_ellipsoid(offsets[regular], covariances[regular])
    return out


def _rounded(value: float):
    return round(value, 4) if np.isfinite(value) else None


def _figure(outcomes: list) -> Figure:
    rms = np.array([o[0] for o in outcomes])
    return Figure(rms, np.concatenate([o[1] for o in outcomes]), np.concatenate([o[2] for o in outcomes]),
                  np.array([o[3] for o in outcomes]), np.array([o[4] for o in outcomes]),
                  np.concatenate([o[5] for o in outcomes]), int(np.isnan(rms).sum()))


def _prediction(figure: Figure, layouts: list[np.ndarray]) -> tuple[float, float, float]:
    """FLE (RMS node error), Fitzpatrick and West's RMS TRE at the nodes and the expected RMS FRE (over the
    repetitions' node layouts), mm."""
    fle = float(np.sqrt(np.mean(figure.node_error_mm**2)))
    traces = np.concatenate([np.trace(rigid_fit_covariance(xyz, xyz), axis1=1, axis2=2) for xyz in layouts])
    fre2 = np.mean([1.0 - 2.0 / len(xyz) for xyz in layouts])
    return fle, float(fle * np.sqrt(np.mean(traces) / 3.0)), float(fle * np.sqrt(fre2))
