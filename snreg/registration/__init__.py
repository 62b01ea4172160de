"""Register the preop node set to the intraop node set and say which hot spot each intraop node came from (docs/design.md, Contracts).

>>> result = register(preop_xyz, intraop_xyz, method="global")
>>> result.transform      # (4, 4) intraop_from_preop
>>> result.pairing        # per intraop node: the SPECT hot spot (preop index) it came from, -1 for none
>>> result.shares         # per intraop node: another node came from the same hot spot

Methods: ``icp``, ``cpd``, ``chamfer`` (the thesis' three) and ``global`` (ours, default).
Each names the pairing rule that fills ``pairing`` (:mod:`snreg.registration.pairing`);
all three rules are in ``pairings``. ``confidence`` is the posterior probability that a
node's claim is right, whichever method produced it (weighed against the candidates of
the global search); ``CONFIDENT`` is the threshold above which claims were right 99.8% of the
time in ``snreg simulate``-style studies at sigma 2-15 mm with every SPECT node present, 99.8% with
one and 99.4% with two missing (four cohorts, issue 20's note); at sigma 20 mm (35 mm per node)
a wrong transform can make confident claims (94% right), so check a noisy registration's RMS.
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass, field

import numpy as np

from snreg import geometry
from snreg.errors import NoFitError
from snreg.registration._covariance import IllConditionedWarning
from snreg.registration._landmark_fit import checkable
from snreg.registration._methods import METHOD_TABLE, nearest_claimants
from snreg.registration._model import source_posterior, squared_distances
from snreg.registration._problem import make_problem
from snreg.registration.confidence import claim_confidence, claim_temperature, posterior_weights, source_probabilities
from snreg.registration.pairing import RULES, pair, shared
from snreg.registration.target import target_error_bound

__all__ = ["register", "solve_transform", "RegistrationResult", "NoFitError", "IllConditionedWarning", "METHODS",
           "METHOD_HELP", "PAIRING_RULE", "CONFIDENT"]

METHODS = ("icp", "cpd", "chamfer", "global")
# One sentence per method for an operator (tooltips): what it does and when it suits.
METHOD_HELP = {
    "icp": "Iterative closest point: each preop node takes the nearest intraop node, the fit is repeated until it "
           "settles; fast, but needs a good initial alignment and pairs every node, extra ones too.",
    "cpd": "Coherent point drift: moves the preop nodes as a blurred cloud onto the intraop nodes, tolerating a "
           "little noise and a few extra nodes; still needs a fair initial alignment.",
    "chamfer": "Chamfer matching (the thesis' method): fits 10 mm spheres around the nodes to each other within the "
               "rotation and translation bounds; a far node can still be paired, so check the warnings.",
    "global": "Global search (default): tries every way of laying three preop nodes on three intraop nodes within "
              "the bounds, allowing missing and extra nodes, and keeps the best; the most reliable, and slower.",
}
PAIRING_RULE = {name: method.rule for name, method in METHOD_TABLE.items()}
CONFIDENT = 0.95


@dataclass
class RegistrationResult:
    """The outcome of :func:`register`; transform ``intraop_from_preop``, distances and RMS in mm.

    ``pairing[m]``: the hot spot (preop index) intraop node m came from, -1 for none (docs/design.md, Contracts); ``distances_mm[m]``:
    its distance from that hot spot mapped (from the nearest for -1); ``rms_mm``: over the hot spots found, each by
    its nearest node (a shared hot spot's other nodes lie beside it by anatomy, not by error); ``confidence[m]``: the
    probability that m's claim is right."""

    method: str
    transform: np.ndarray
    pairing: np.ndarray
    distances_mm: np.ndarray
    rms_mm: float
    confidence: np.ndarray
    pairing_rule: str
    pairings: dict[str, np.ndarray] = field(default_factory=dict)
    score: float = float("nan")
    initial: np.ndarray | None = None      # (4, 4) the rough intraop_from_preop the search started from
    target_error_mm: np.ndarray | None = None   # (N,) per preop node: 90% bound on |mapped - where it really is|
    missing: np.ndarray | None = None           # (N,) bool: hot spots no intraop node came from
    leave_one_out_mm: np.ndarray | None = None  # (M,) per node from a hot spot: its distance when the others register
    landmark_residual_mm: dict[str, float] = field(default_factory=dict)        # landmark pair name -> mm
    landmark_leave_one_out_mm: dict[str, float] = field(default_factory=dict)   # ... when the rest alone register
    landmarks_suspect: list[str] = field(default_factory=list)   # pairs that contradict the rest: left out of the fit

    @property
    def shares(self) -> np.ndarray:
        """(M,) bool: another intraop node came from the same hot spot ("SN5 -> P3 (with SN4)")."""
        return shared(self.pairing)

    @property
    def landmarks_checkable(self) -> bool:
        """False when the points cannot reveal a wrong landmark: no landmark pair's leave-one-out fit is determined
        (e.g. 1 node and 2 landmarks, 3 points in all); True without landmark pairs. Screens say it in words
        (:func:`~snreg.registration.landmark_report.landmark_notes`)."""
        return checkable(self.landmark_leave_one_out_mm)

    @property
    def confident(self) -> np.ndarray:
        """Per intraop node: is its claim confident enough to act on (>= ``CONFIDENT``)?"""
        return self.confidence >= CONFIDENT


def register(preop, intraop, method: str = "global", *, preop_labels=None, intraop_labels=None, initial=None,
             max_rotation_deg: float = 60.0, max_translation_mm: float = 60.0, seed: int = 0,
             preop_landmarks=None, intraop_landmarks=None, landmark_sd_mm: float = 2.0,
             intraop_cov=None, preop_cov=None, down=None, down_sd_deg: float = 10.0,
             pairing_rule: str | None = None, **options) -> RegistrationResult:
    """Register preop (N, 3) to intraop (M, 3) nodes in mm and say which hot spot every intraop node came from.

    ``initial`` is a rough ``intraop_from_preop`` (identity if None); the search stays
    within ``max_rotation_deg`` and ``max_translation_mm`` (displacement of the preop
    centroid) of it: a pairing whose best fit leans past them is fitted within them, and
    :class:`NoFitError` says that no pairing fits only when the nodes fit far better beyond
    them (a million to one). Labels such as ``"OBT R"`` forbid left/right crossings and favour
    matching stations. ``pairing_rule`` overrides the method's rule; ``options`` go to
    the method's solver (e.g. ``w`` for cpd, ``form`` for chamfer). ``intraop_cov`` (M, 3, 3) and
    ``preop_cov`` (N, 3, 3) are each node's own error covariance in mm^2 (or one sd in mm for all): ``global``, the
    confidence, the target-error bounds and leave-one-out weigh every node by it (a stereo fix is uncertain mostly
    along its viewing ray); icp, cpd and chamfer take only its mean size, to weigh landmark pairs against the nodes.
    None keeps the isotropic model exactly.
    ``preop_landmarks``/``intraop_landmarks`` ({name: (3,) mm}, or node sets whose ids are the names) are paired by
    name (after :func:`~snreg.landmarks.landmark_key`: case and spaces aside) and enter every method's fit with their
    correspondence known and ``landmark_sd_mm`` of error per axis; with them one or two nodes register (3 points in
    all, 1 intraop node at least, ``global`` only); a pair that contradicts the rest is left out and named in
    ``landmarks_suspect``; ``landmarks_checkable`` is False when too few points remain to reveal a wrong one. ``down`` (down in the preop frame, down in the intraop frame)
    is the gravity prior: without ``initial`` the search starts from the two downs aligned and the centroids
    matched, covers every heading about the vertical and tilts within a few ``down_sd_deg`` (the tilt's prior sd),
    and bounds the centroids' displacement by ``max_translation_mm``; ``initial`` still overrides it.
    Everything after ``method`` is keyword-only. Raises ValueError with a message a user understands on bad
    input, an unknown method or option included.
    """
    _check_method(method, options)
    rule = pairing_rule or PAIRING_RULE[method]
    if rule not in RULES:
        raise ValueError(f"unknown pairing rule {rule!r}; choose one of {', '.join(RULES)}")
    problem = make_problem(preop, intraop, preop_labels=preop_labels, intraop_labels=intraop_labels,
                           initial=initial, max_rotation_deg=max_rotation_deg,
                           max_translation_mm=max_translation_mm, seed=seed, intraop_cov=intraop_cov,
                           preop_cov=preop_cov, preop_landmarks=preop_landmarks, intraop_landmarks=intraop_landmarks,
                           landmark_sd_mm=landmark_sd_mm, down=down, down_sd_deg=down_sd_deg)
    every = problem.landmarks
    fit = METHOD_TABLE[method].fit(problem, options)
    problem, correction, base, candidates = fit.problem, fit.correction, fit.base, fit.candidates

    ranked, weights = posterior_weights(candidates)
    sources, _ = source_probabilities(problem, ranked)
    # global names the most probable source over its candidates; the others label at their own transform
    own_sources = sources if fit.sources_over_candidates else source_posterior(problem, base)
    pairings = {r: pair(r, problem, correction, own_sources) for r in RULES}
    pairing = pairings[rule]
    claims = source_probabilities(problem, ranked, claim_temperature(problem, ranked[0]))
    confidence = claim_confidence(pairing, *claims)
    moved = geometry.apply(correction, problem.preop)
    d2 = squared_distances(moved, problem.intraop)
    # a node from no hot spot: its distance to the nearest mapped hot spot, a remark for screens, not a pairing
    distances = np.sqrt(np.where(pairing >= 0, d2[np.maximum(pairing, 0), np.arange(len(pairing))], d2.min(axis=0)))
    nearest = nearest_claimants(pairing, distances)
    rms = float(np.sqrt(np.mean(distances[nearest] ** 2))) if nearest.any() else float("nan")
    residual, loo = METHOD_TABLE[method].residuals(fit, every)
    return RegistrationResult(method=method, transform=correction @ problem.initial, pairing=pairing,
                              distances_mm=distances, rms_mm=rms, confidence=confidence, pairing_rule=rule,
                              pairings=pairings, score=base.score, initial=problem.initial,
                              target_error_mm=target_error_bound(problem, correction, ranked, weights),
                              missing=~np.isin(np.arange(len(problem.preop)), pairing),
                              leave_one_out_mm=METHOD_TABLE[method].leave_one_out(fit, pairing, nearest),
                              landmark_residual_mm=residual, landmark_leave_one_out_mm=loo,
                              landmarks_suspect=list(fit.suspects))


def solve_transform(preop, intraop, method: str = "global", *, preop_labels=None, intraop_labels=None,
                    initial=None, max_rotation_deg: float = 60.0, max_translation_mm: float = 60.0, seed: int = 0,
                    intraop_cov=None, preop_cov=None, down=None, down_sd_deg: float = 10.0, **options) -> np.ndarray:
    """The method's transform estimate alone, (4, 4) ``intraop_from_preop``: the solver without the pairing and the
    confidence that :func:`register` adds (what ``snreg bench`` times as "solver"). Arguments as :func:`register`."""
    _check_method(method, options)
    problem = make_problem(preop, intraop, preop_labels=preop_labels, intraop_labels=intraop_labels,
                           initial=initial, max_rotation_deg=max_rotation_deg,
                           max_translation_mm=max_translation_mm, seed=seed, intraop_cov=intraop_cov,
                           preop_cov=preop_cov, down=down, down_sd_deg=down_sd_deg)
    return METHOD_TABLE[method].solve(problem, options) @ problem.initial


def _check_method(method: str, options: dict) -> None:
    """ValueError for a method that does not exist or an option its solver does not take."""
    if method not in METHODS:
        raise ValueError(f"unknown registration method {method!r}; choose one of {', '.join(METHODS)}")
    known = [name for name, parameter in inspect.signature(METHOD_TABLE[method].solver).parameters.items()
             if parameter.kind is inspect.Parameter.KEYWORD_ONLY]
    unknown = sorted(set(options) - set(known))
    if unknown:
        raise ValueError(f"unknown option{'s' if len(unknown) > 1 else ''} {', '.join(map(repr, unknown))} for method "
                         f"{method!r}; its options are {', '.join(known)}")
