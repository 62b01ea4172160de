"""The thesis' simulation protocol (§5.4.2) run on a cohort, one seeded trial at a time.

Per trial: intraop = preop + N(0, sigma^2) per axis; ``n_extra`` extra intraop nodes offset
5-15 mm (random sign) per coordinate from random true intraop nodes; the intraop order
shuffled; the preop set moved by a random rigid transform (yaw, pitch, roll uniform in
[0, 30] degrees about its centroid, translation uniform in [-20, 20] mm per axis); then
every method registers the moved preop set to the intraop set.

Beyond the thesis (surgery is not like its protocol): ``n_missing`` true intraop nodes are then
left out, chosen at random, so that many SPECT nodes have no intraop partner (not removed yet,
or never found); at least 3 true nodes remain. Extra nodes hosted on a left-out node stay. The
left-out nodes' would-be intraop positions are kept as the truth for the target error. With
``n_missing = 0`` a trial is the thesis trial exactly (the leaving out draws from its own stream).

Intraop labels (used only by ``+labels`` methods) copy the preop station and side; an
extra node takes its host's label; each station is then wrong with probability
``STATION_ERROR`` (thesis Table 1: stations were revised in 11 of 13 patients), the side
never.

With ``start="gravity"`` (issue 30) the preop set is not roughly aligned: it is turned any way (a uniformly
random rotation) and shifted anywhere within +-``GRAVITY_SHIFT_MM`` per axis, and registration is given gravity
instead: down in each frame, the patient tilted ``TABLE_TILT_DEG`` head down (Trendelenburg), the preop down from
a tilt entered with ``tilt_sd_deg`` of error, the intraop down from the IMU off by ``imu_down_sd_deg``.

With ``anisotropy`` R above 1 (issue 28) each true intraop node is seen along its own viewing ray (within
``VIEW_CONE_DEG`` of the camera's axis) and its error along that ray is R times its error across it, the per-axis RMS
still sigma; the trial carries every node's covariance (an extra inherits its host's error and covariance, as it
inherits its noisy position), which ``+cov`` methods are given.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial.distance import cdist
from scipy.spatial.transform import Rotation

from snreg import geometry
from snreg.labels import STATIONS, parse_label
from snreg.errors import TooFewPairsError
from snreg.registration import NoFitError, register
from snreg.registration.pairing import RULES, pairing_at

__all__ = ["Trial", "make_trial", "run_trial", "TrialOutcome", "claims_right", "STATION_ERROR"]

STATION_ERROR = 0.3
VIEW_CONE_DEG = 40.0          # viewing rays of anisotropic trials: within this of the camera's axis
GRAVITY_SHIFT_MM = 300.0      # gravity-start trials: the preop set anywhere within this per axis
TABLE_TILT_DEG = 30.0         # the head-down tilt of robotic prostatectomy


@dataclass(frozen=True)
class Trial:
    """One simulated case. ``truth[m]`` is intraop m's preop index, -1 for an extra node; ``source[m]`` the hot spot
    intraop m came from (its own preop node, or for an extra the node it lies beside); ``left_out`` the preop indices
    without an intraop node and ``left_out_xyz`` (L, 3) where their intraop nodes would have been."""

    patient: str
    sigma: float
    n_extra: int
    rep: int
    preop: np.ndarray           # (N, 3) original preop positions (the intraop frame)
    moved_preop: np.ndarray     # (N, 3) what registration sees
    intraop: np.ndarray         # (M, 3)
    truth: np.ndarray           # (M,)
    preop_labels: list[str]
    intraop_labels: list[str]
    intraop_from_moved: np.ndarray
    n_missing: int = 0
    left_out: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    left_out_xyz: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    source: np.ndarray | None = None
    intraop_cov: np.ndarray | None = None       # (M, 3, 3) mm^2: each intraop node's error covariance
    preop_landmarks: dict | None = None         # {name: (3,)} in the moved frame registration sees
    intraop_landmarks: dict | None = None       # {name: (3,)} where they were touched (a swapped name stays swapped)
    landmark_sd_mm: float = 2.0
    swapped: tuple[str, ...] = ()               # the two landmark names exchanged on the intraop side, if any
    down: tuple[np.ndarray, np.ndarray] | None = None   # gravity start: (down in the moved preop frame, intraop)

    def __post_init__(self):
        if self.source is None:                     # without hosts known, an extra's only right claim is -1
            object.__setattr__(self, "source", np.where(self.truth >= 0, self.truth, -1))


def make_trial(patient: str, preop: np.ndarray, labels: list[str], sigma: float, n_extra: int, rep: int,
               seed_words: tuple[int, ...], n_missing: int = 0, anisotropy: float = 1.0, min_true: int = 3,
               start: str = "rough", tilt_sd_deg: float = 8.0, imu_down_sd_deg: float = 1.0) -> Trial:
    """One trial; ValueError when ``n_missing`` would leave fewer than ``min_true`` (3; 1 with landmarks) true
    intraop nodes. ``anisotropy``: the error along each node's viewing ray over the error across it (1: the thesis'
    isotropic error)."""
    if not 0 <= n_missing <= len(preop) - min_true:
        raise ValueError(f"{patient}: {len(preop)} preop nodes leave fewer than {min_true} true intraop nodes when "
                         f"{n_missing} are left out")
    seeds = np.random.SeedSequence(seed_words)
    rng = np.random.default_rng(seeds)
    label_rng = np.random.default_rng(seeds.spawn(1)[0])   # label noise leaves the geometry's stream alone
    n = len(preop)
    if anisotropy == 1.0:
        noisy = preop + rng.normal(0.0, sigma, preop.shape)
        cov = np.broadcast_to(sigma**2 * np.eye(3), (n, 3, 3))
    else:
        cov = _viewing_covariances(n, sigma, anisotropy, np.random.default_rng(seeds.spawn(2)[1]))
        noisy = preop + np.einsum("nij,nj->ni", np.linalg.cholesky(cov), rng.standard_normal(preop.shape))
    hosts = rng.integers(0, n, n_extra)
    offsets = rng.uniform(5.0, 15.0, (n_extra, 3)) * rng.choice([-1.0, 1.0], (n_extra, 3))
    intraop = np.vstack([noisy, noisy[hosts] + offsets])
    intraop_cov = np.concatenate([cov, cov[hosts]])
    truth = np.concatenate([np.arange(n), np.full(n_extra, -1)])
    source = np.concatenate([np.arange(n), hosts])
    intra_labels = [_relabel(label, label_rng) for label in list(labels) + [labels[h] for h in hosts]]
    order = rng.permutation(len(intraop))
    intraop, truth, source, intraop_cov = intraop[order], truth[order], source[order], intraop_cov[order]
    intra_labels = [intra_labels[k] for k in order]

    yaw, pitch, roll = rng.uniform(0.0, 30.0, 3)
    shift = rng.uniform(-20.0, 20.0, 3)
    centre = preop.mean(axis=0)
    rotation = geometry.rotation_from_euler(yaw, pitch, roll)
    moved_from_original = geometry.make_transform(rotation, centre + shift - rotation @ centre)
    down = None
    if start == "gravity":
        moved_from_original, down = _gravity_start(centre, np.random.default_rng(seeds.spawn(3)[2]), tilt_sd_deg,
                                                   imu_down_sd_deg)
    missing_rng = np.random.default_rng(seeds.spawn(1)[0])
    left_out = np.sort(missing_rng.choice(n, n_missing, replace=False)) if n_missing else np.zeros(0, dtype=int)
    keep = ~np.isin(truth, left_out)
    return Trial(patient, float(sigma), int(n_extra), int(rep), preop, geometry.apply(moved_from_original, preop),
                 intraop[keep], truth[keep], list(labels), [lab for lab, k in zip(intra_labels, keep) if k],
                 geometry.invert(moved_from_original), int(n_missing), left_out, noisy[left_out], source[keep],
                 intraop_cov[keep], down=down)


def _gravity_start(centre: np.ndarray, rng: np.random.Generator, tilt_sd_deg: float,
                   imu_down_sd_deg: float) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """A preop frame turned any way and shifted anywhere (``moved_from_original``), and the downs registration is
    given: the table's tilt entered with its error in the preop frame, the IMU's with its error in the intraop."""
    turn = Rotation.random(random_state=rng)
    shift = rng.uniform(-GRAVITY_SHIFT_MM, GRAVITY_SHIFT_MM, 3)
    moved_from_original = geometry.make_transform(turn.as_matrix(), centre + shift - turn.apply(centre))
    tilt = np.radians(TABLE_TILT_DEG)
    true_down = np.array([0.0, np.cos(tilt), np.sin(tilt)])          # LPS, supine, head down: posterior and cranial
    entered = np.radians(TABLE_TILT_DEG + rng.normal(0.0, tilt_sd_deg))
    entered_down = np.array([0.0, np.cos(entered), np.sin(entered)])
    axis = rng.normal(size=3)
    imu_error = Rotation.from_rotvec(np.radians(imu_down_sd_deg) * rng.normal() * axis / np.linalg.norm(axis))
    return moved_from_original, (turn.apply(entered_down), imu_error.apply(true_down))


def _viewing_covariances(n: int, sigma: float, anisotropy: float, rng: np.random.Generator) -> np.ndarray:
    """(n, 3, 3) covariances with sd ``anisotropy`` times larger along a viewing ray (each node its own, within
    ``VIEW_CONE_DEG`` of z) than across it, the per-axis RMS ``sigma``."""
    across = sigma / np.sqrt((anisotropy**2 + 2.0) / 3.0)
    tilt = np.radians(VIEW_CONE_DEG) * np.sqrt(rng.uniform(0.0, 1.0, n))
    turn = rng.uniform(0.0, 2.0 * np.pi, n)
    rays = np.c_[np.sin(tilt) * np.cos(turn), np.sin(tilt) * np.sin(turn), np.cos(tilt)]
    return across**2 * (np.eye(3) + (anisotropy**2 - 1.0) * rays[:, :, None] * rays[:, None, :])


def _relabel(label: str, rng: np.random.Generator) -> str:
    station, side = parse_label(label)
    if station and rng.random() < STATION_ERROR:
        station = rng.choice(sorted(set(STATIONS.values()) - {station}))
    return f"{station} {side}".strip()


@dataclass
class TrialOutcome:
    """What one method did on one trial (a row of the trial CSV) plus per-node confidences.

    ``confidence``/``correct``: per true intraop node; ``claim_confidence``/``claim_correct``: per intraop node, extras
    included (a claim is the reported hot spot or -1, scored by :func:`claims_right`); ``bound_mm``/``left_out_error_mm``: per left-out preop node,
    the reported 90% target-error bound and the actual distance of its mapped position from where it really is.
    """

    row: dict
    confidence: np.ndarray
    correct: np.ndarray
    claim_confidence: np.ndarray
    claim_correct: np.ndarray
    bound_mm: np.ndarray
    left_out_error_mm: np.ndarray


def claims_right(trial: Trial, pairing: np.ndarray) -> np.ndarray:
    """(M,) bool per intraop node: is its claim right (docs/design.md, Contracts)? A true node is right with its own hot spot; an extra
    beside hot spot j is right with j or -1."""
    pairing = np.asarray(pairing, dtype=int)
    return np.where(trial.truth >= 0, pairing == trial.truth, (pairing == trial.source) | (pairing == -1))


def oracle_success(trial: Trial) -> dict[str, bool]:
    """Pairing success of the true nodes with the true transform: nearest-neighbour (the thesis rule), one-to-one
    assignment, the most probable under each node's covariance (``oracle_nearest_cov``), and the hot-spot labelling at
    the true sigma (what global's own pairing rule reaches once the
    transform is known; :func:`pairing_at`)."""
    true = trial.truth >= 0
    d2 = cdist(trial.preop, trial.intraop, "sqeuclidean")
    nearest = np.argmin(d2, axis=0)
    residual = trial.preop[:, None, :] - trial.intraop[None]
    mahalanobis = np.einsum("nmi,mij,nmj->nm", residual, np.linalg.inv(trial.intraop_cov + 1e-9 * np.eye(3)), residual)
    nearest_cov = np.argmin(mahalanobis + np.linalg.slogdet(trial.intraop_cov + 1e-9 * np.eye(3))[1][None], axis=0)
    rows, cols = linear_sum_assignment(d2)
    one_to_one = np.full(len(trial.intraop), -1)
    one_to_one[cols] = rows
    if min(len(trial.preop), len(trial.intraop)) >= 3:
        model = pairing_at(trial.preop, trial.intraop, np.eye(4), max(trial.sigma, 1.0))
    else:                            # one or two nodes: the model's labelling is the nearest one
        model = nearest
    return {"oracle_nearest": bool(np.all(nearest[true] == trial.truth[true])),
            "oracle_nearest_cov": bool(np.all(nearest_cov[true] == trial.truth[true])),
            "oracle_one_to_one": bool(np.all(one_to_one[true] == trial.truth[true])),
            "oracle_model": bool(np.all(model[true] == trial.truth[true])),
            "oracle_nearest_all_claims": bool(np.all(claims_right(trial, nearest)))}


def error_stats(trial: Trial) -> dict[str, float]:
    """Introduced errors and the max error ratio (thesis Fig. 22-23) of the true intraop nodes."""
    true = np.flatnonzero(trial.truth >= 0)
    partner = trial.truth[true]
    d = cdist(trial.preop, trial.intraop[true])      # (N, T)
    error = d[partner, np.arange(len(true))]
    d[partner, np.arange(len(true))] = np.inf
    ratio = error / d.min(axis=0)
    return {"mean_error_mm": float(error.mean()), "max_error_mm": float(error.max()), "max_error_ratio": float(ratio.max())}


def run_trial(trial: Trial, method: str, use_labels: bool = False, use_cov: bool = False, use_landmarks: bool = False,
              **options) -> TrialOutcome:
    """Register one trial with ``method`` (given the labels, the nodes' covariances and the landmarks, when asked); a
    refusal (no pairing fits the bounds, or too few nodes without landmarks) counts as a failure."""
    start = time.perf_counter()
    true = trial.truth >= 0
    marks = {"preop_landmarks": trial.preop_landmarks, "intraop_landmarks": trial.intraop_landmarks,
             "landmark_sd_mm": trial.landmark_sd_mm} if use_landmarks and trial.preop_landmarks else {}
    if trial.down is not None:
        marks["down"] = trial.down
    try:
        result = register(trial.moved_preop, trial.intraop, method=method,
                          preop_labels=trial.preop_labels if use_labels else None,
                          intraop_labels=trial.intraop_labels if use_labels else None,
                          intraop_cov=trial.intraop_cov if use_cov else None, **marks, **options)
    except (NoFitError, TooFewPairsError):          # a refusal: no fit within the bounds, or too few side-true pairs
        result = None
    except ValueError:
        if len(trial.moved_preop) >= 3 and len(trial.intraop) >= 3:
            raise                                   # only a patient with too few nodes may be refused here
        result = None
    elapsed_ms = (time.perf_counter() - start) * 1e3
    if result is None:
        nan = float("nan")
        row = {"success": False, "all_claims": False, "refused": True, "landmarks_flagged": False,
               "swapped_flagged": False,
               **{f"success_{rule}": False for rule in RULES}, **{f"all_claims_{rule}": False for rule in RULES},
               "extras_none": 0, "shared": 0, "rms_mm": nan, "tre_mm": nan, "min_confidence": 0.0,
               "time_ms": elapsed_ms}
        m = len(trial.intraop)
        return TrialOutcome(row, np.zeros(int(true.sum())), np.zeros(int(true.sum()), bool), np.zeros(m),
                            np.zeros(m, bool), np.full(len(trial.left_out), np.inf), np.full(len(trial.left_out), nan))
    correct = result.pairing[true] == trial.truth[true]
    claims = claims_right(trial, result.pairing)
    mapped = geometry.apply(result.transform, trial.moved_preop)
    tre = np.sqrt(np.mean(np.sum((mapped - trial.preop) ** 2, axis=1)))
    row = {
        "success": bool(np.all(correct)),
        "all_claims": bool(np.all(claims)),
        "refused": False,
        **{f"success_{rule}": bool(np.all(p[true] == trial.truth[true])) for rule, p in result.pairings.items()},
        **{f"all_claims_{rule}": bool(np.all(claims_right(trial, p))) for rule, p in result.pairings.items()},
        "extras_none": int(np.sum(result.pairing[~true] == -1)),
        "shared": int(np.sum(result.shares)),
        "rms_mm": result.rms_mm,
        "tre_mm": float(tre),
        "min_confidence": float(result.confidence[true].min()),
        "time_ms": elapsed_ms,
        "landmarks_flagged": bool(result.landmarks_suspect),
        "swapped_flagged": bool(set(result.landmarks_suspect) & set(trial.swapped)),
    }
    left_out_error = np.linalg.norm(mapped[trial.left_out] - trial.left_out_xyz, axis=1)
    return TrialOutcome(row, result.confidence[true], correct, result.confidence, claims,
                        result.target_error_mm[trial.left_out], left_out_error)
