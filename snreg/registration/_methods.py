"""The registration methods as a table of small objects with one interface: fit, then landmark residuals and
leave-one-out, the same for every method.

Why: a landmark pair's correspondence is known, so every method fits with it (issue 34: icp, cpd and chamfer used
to fit without the pairs and still report their residuals). Each method's :meth:`Method.fit` runs its own solver on
the landmark sets :func:`~snreg.registration._landmark_fit.trusted_landmarks` tries (every pair, then leaving out one
or two), judged by the one model every method's pairing is scored by; so a suspect, a residual and a leave-one-out
mean the same whichever method fitted. ``global`` keeps its search's candidates; the nearest-rule methods (the
thesis' three) are judged against the global search's candidates at their own fit, within the bounds.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from snreg import geometry
from snreg.errors import NoFitError
from snreg.registration._bounded import fit_within_bounds
from snreg.registration._chamfer import solve_chamfer
from snreg.registration._cpd import solve_cpd
from snreg.registration._global import local_moves, solve_global
from snreg.registration._icp import solve_icp
from snreg.registration._landmark_fit import landmark_residuals, trusted_landmarks
from snreg.registration._landmarks import Landmarks
from snreg.registration._model import (MIN_PAIRS, Candidate, assign, evaluate, fit_pairs, squared_distances,
                                       unmodelled_grid)
from snreg.registration._problem import Problem
from snreg.registration.pairing import pair

__all__ = ["Fit", "Method", "METHOD_TABLE", "nearest_claimants"]


@dataclass(frozen=True)
class Fit:
    """A method's fit: the problem with the landmark pairs it trusts (the suspects left out), its correction (initial-
    aligned frame), the model's candidate at that correction (``base``), every candidate the confidence weighs (best
    first for ``global``; ``base`` first otherwise), the suspects' names, and whether the hot spots each node came
    from are read over the candidates (``global``) or at the method's own fit."""

    problem: Problem
    correction: np.ndarray
    base: Candidate
    candidates: list[Candidate] = field(default_factory=list)
    suspects: tuple[str, ...] = ()
    sources_over_candidates: bool = False

    @property
    def score(self) -> float:
        """The model's score of the fit's pairing (nats, lower is better): how landmark sets are compared."""
        return self.base.score


class Method:
    """One registration method: ``solver`` (the private solver, options keyword-only) and its pairing ``rule``."""

    name: str = ""
    rule: str = ""
    solver: Callable = None

    def fit(self, problem: Problem, options: dict) -> Fit:
        """The method's fit with the landmark pairs it trusts (suspects left out)."""
        fit, suspects = trusted_landmarks(problem, lambda trial: self._fit_one(trial, options))
        return self._finish(fit, suspects)

    def solve(self, problem: Problem, options: dict) -> np.ndarray:
        """The solver's correction alone (initial-aligned frame): what ``snreg bench`` times as "solver"."""
        return type(self).solver(problem, **options)

    def _fit_one(self, problem: Problem, options: dict) -> Fit:
        raise NotImplementedError

    def _finish(self, fit: Fit, suspects: tuple[str, ...]) -> Fit:
        return Fit(fit.problem, fit.correction, fit.base, fit.candidates, suspects, fit.sources_over_candidates)

    @staticmethod
    def residuals(fit: Fit, every: Landmarks | None) -> tuple[dict[str, float], dict[str, float]]:
        """({name: mm} residual, {name: mm} leave-one-out) of ``every`` landmark pair given (suspects included)."""
        if every is None or not len(every):
            return {}, {}
        return landmark_residuals(fit.problem, fit.base, fit.correction, every)

    @staticmethod
    def leave_one_out(fit: Fit, pairing: np.ndarray, nearest: np.ndarray) -> np.ndarray:
        """(M,) per intraop node from a hot spot: its distance from it when the other hot spots' nearest nodes (and the
        trusted landmark pairs) alone fit the correction (NaN for a node from none, and when too few points remain);
        with covariances or landmarks the weighted fit at the unmodelled error the best candidate makes most likely."""
        problem, base = fit.problem, fit.base
        out = np.full(len(pairing), np.nan)
        sigma = None
        if problem.weighted and base.fit_weights is not None:
            sigma = float(unmodelled_grid(problem)[int(np.argmax(base.fit_weights))])
        for j in np.flatnonzero(pairing >= 0):
            rest = np.flatnonzero(nearest & (pairing != pairing[j]))
            if len(rest) < problem.min_pairs:
                continue
            if problem.weighted:
                assignment = np.full(len(pairing), -1)
                assignment[rest] = pairing[rest]
                correction = fit_pairs(problem, assignment, sigma)
            else:
                correction = geometry.kabsch(problem.preop[pairing[rest]], problem.intraop[rest])
            out[j] = float(np.linalg.norm(geometry.apply(correction, problem.preop[pairing[j]][None])[0]
                                          - problem.intraop[j]))
        return out


class _Global(Method):
    name, rule = "global", "hot_spot"
    solver = staticmethod(solve_global)

    def solve(self, problem: Problem, options: dict) -> np.ndarray:
        return solve_global(problem, **options)[0].correction

    def _fit_one(self, problem: Problem, options: dict) -> Fit:
        candidates = solve_global(problem, **options)
        return Fit(problem, candidates[0].correction, candidates[0], candidates, sources_over_candidates=True)


class _Nearest(Method):
    """A thesis method (icp, cpd, chamfer): its solver's correction, fitted within the bounds when it leans past them,
    weighed against the global search's candidates (the confidence)."""

    rule = "nearest"

    def fit(self, problem: Problem, options: dict) -> Fit:
        if min(len(problem.preop), len(problem.intraop)) < MIN_PAIRS:
            raise ValueError(f"{self.name} needs at least {MIN_PAIRS} nodes on each side; with fewer, landmarks and "
                             "the global method register them")
        fit = super().fit(problem, options)
        # The confidence weighs this pairing against the global search's hypotheses; when the nodes fit far better
        # beyond the bounds, that search refuses, and this method's fit inside them is refused the same way.
        candidates = [fit.base] + solve_global(fit.problem) + local_moves(fit.problem, fit.base)
        return Fit(fit.problem, fit.correction, fit.base, candidates, fit.suspects)

    def _fit_one(self, problem: Problem, options: dict) -> Fit:
        correction = type(self).solver(problem, **options)
        if not problem.within_bounds(correction):
            correction = self._within_bounds(problem, correction)
        return Fit(problem, correction, _candidate_at(problem, correction))

    def _within_bounds(self, problem: Problem, correction: np.ndarray) -> np.ndarray:
        """The fit within the bounds of the pairing the correction makes by the nearest rule (each hot spot by its
        nearest node), landmark pairs included; NoFitError when that pairing has fewer than 3 nodes."""
        d2 = squared_distances(geometry.apply(correction, problem.preop), problem.intraop)
        partner = np.argmin(d2, axis=0)
        chosen = nearest_claimants(partner, d2[partner, np.arange(len(partner))])
        if chosen.sum() < MIN_PAIRS:
            angle, shift = problem.correction_size(correction)
            raise NoFitError(f"{self.name} moved {float(angle):.0f} degrees and {float(shift):.0f} mm from the initial "
                             f"alignment, beyond the bounds ({problem.max_rotation_deg:g} degrees, "
                             f"{problem.max_translation_mm:g} mm): give an initial alignment closer to the truth, "
                             "use the anatomical labels, or use the global method")
        source, target = problem.preop[partner[chosen]], problem.intraop[chosen]
        if problem.n_landmarks:
            source = np.vstack([source, problem.landmarks.preop])
            target = np.vstack([target, problem.landmarks.intraop])
        return fit_within_bounds(problem, source, target)


class _Icp(_Nearest):
    name = "icp"
    solver = staticmethod(solve_icp)


class _Cpd(_Nearest):
    name = "cpd"
    solver = staticmethod(solve_cpd)


class _Chamfer(_Nearest):
    name = "chamfer"
    solver = staticmethod(solve_chamfer)


METHOD_TABLE: dict[str, Method] = {method.name: method for method in (_Icp(), _Cpd(), _Chamfer(), _Global())}


def _candidate_at(problem: Problem, correction: np.ndarray) -> Candidate:
    """The model's pairing at another method's correction (sigma from its nearest-neighbour residual), scored."""
    d2 = squared_distances(geometry.apply(correction, problem.preop), problem.intraop)
    k = min(len(problem.preop), len(problem.intraop))
    sigma = float(np.sqrt(max(np.sort(d2.min(axis=0))[:k].sum() / max(3 * k - 6, 1), 1.0)))
    assignment = assign(problem, correction, sigma)
    if np.sum(assignment >= 0) < max(problem.min_pairs, 1):     # the nearest pairs then, one-to-one
        assignment = pair("one_to_one", problem, correction, None)
    return evaluate(problem, assignment)


def nearest_claimants(pairing: np.ndarray, distances: np.ndarray) -> np.ndarray:
    """(M,) bool: the node nearest its hot spot among those that claim it; one per hot spot found. The RMS and the
    leave-one-out fits count these: a shared hot spot's other nodes lie beside it by anatomy, not by error."""
    order = np.lexsort((distances, pairing))
    first = np.ones(len(order), bool)
    first[1:] = pairing[order][1:] != pairing[order][:-1]
    chosen = np.zeros(len(pairing), bool)
    chosen[order[first]] = True
    return chosen & (pairing >= 0)
