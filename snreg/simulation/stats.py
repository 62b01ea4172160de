"""Statistics of a simulation study: accuracy with Wilson intervals, paired tests, calibration."""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np
from scipy import stats

__all__ = ["Accuracy", "accuracy", "select", "paired_tests", "extras_breakdown", "calibration", "threshold_for"]


@dataclass(frozen=True)
class Accuracy:
    successes: int
    trials: int
    low: float
    high: float

    @property
    def rate(self) -> float:
        return self.successes / self.trials if self.trials else float("nan")

    def __str__(self) -> str:
        return f"{100 * self.rate:.1f}% [{100 * self.low:.1f}, {100 * self.high:.1f}]"


def accuracy(flags) -> Accuracy:
    """Success rate with a 95% Wilson score interval."""
    flags = np.asarray(flags, dtype=bool)
    k, n = int(flags.sum()), len(flags)
    if n == 0:
        return Accuracy(0, 0, float("nan"), float("nan"))
    ci = stats.binomtest(k, n).proportion_ci(confidence_level=0.95, method="wilson")
    return Accuracy(k, n, float(ci.low), float(ci.high))


def select(rows: list[dict], **where) -> list[dict]:
    return [r for r in rows if all(r[k] == v for k, v in where.items())]


def column(rows: list[dict], key: str) -> np.ndarray:
    return np.array([r[key] for r in rows], dtype=float)


def _aligned(rows: list[dict], method: str) -> list[dict]:
    subset = select(rows, method=method)
    return sorted(subset, key=lambda r: (r["patient"], r["sigma"], r["n_extra"], r["rep"]))


def paired_tests(rows: list[dict], methods: list[str]) -> list[dict]:
    """Every method pair on the same trials: paired t-test on RMS (Bonferroni) and exact McNemar on success."""
    pairs = list(combinations(methods, 2))
    out = []
    for a, b in pairs:
        ra, rb = _aligned(rows, a), _aligned(rows, b)
        rms_a, rms_b = column(ra, "rms_mm"), column(rb, "rms_mm")
        t = stats.ttest_rel(rms_a, rms_b)
        sa, sb = column(ra, "success").astype(bool), column(rb, "success").astype(bool)
        only_a, only_b = int(np.sum(sa & ~sb)), int(np.sum(~sa & sb))
        mcnemar = stats.binomtest(only_a, only_a + only_b, 0.5).pvalue if only_a + only_b else 1.0
        out.append({"a": a, "b": b, "rms_a": float(rms_a.mean()), "rms_b": float(rms_b.mean()),
                    "t_p": float(t.pvalue), "t_p_bonferroni": min(1.0, float(t.pvalue) * len(pairs)),
                    "only_a": only_a, "only_b": only_b, "mcnemar_p": float(mcnemar),
                    "mcnemar_p_bonferroni": min(1.0, float(mcnemar) * len(pairs))})
    return out


def extras_breakdown(rows: list[dict], method: str, extras: list[int]) -> list[dict]:
    """RMS and accuracy by number of extra nodes (thesis Table 7), Welch t-test against 0 extras."""
    base = column(select(rows, method=method, n_extra=extras[0]), "rms_mm")
    out = []
    for e in extras:
        subset = select(rows, method=method, n_extra=e)
        rms = column(subset, "rms_mm")
        p = float(stats.ttest_ind(base, rms, equal_var=False).pvalue) if e != extras[0] else float("nan")
        out.append({"n_extra": e, "rms_mean": float(rms.mean()), "rms_std": float(rms.std(ddof=1)) if len(rms) > 1 else 0.0,
                    "p_vs_first": p, "accuracy": accuracy(column(subset, "success"))})
    return out


CONFIDENCE_BINS = (0.0, 0.5, 0.7, 0.8, 0.9, 0.95, 0.99, 1.0 + 1e-9)


def calibration(confidence: np.ndarray, correct: np.ndarray) -> list[dict]:
    """Per confidence bin: number of node pairings, mean confidence, fraction right."""
    out = []
    for lo, hi in zip(CONFIDENCE_BINS[:-1], CONFIDENCE_BINS[1:]):
        inside = (confidence >= lo) & (confidence < hi)
        if inside.any():
            out.append({"low": lo, "high": min(hi, 1.0), "n": int(inside.sum()),
                        "mean_confidence": float(confidence[inside].mean()), "right": float(correct[inside].mean())})
    return out


def threshold_for(confidence: np.ndarray, correct: np.ndarray, precision: float = 0.99) -> tuple[float, float, float]:
    """(threshold, precision above it, coverage): the lowest threshold whose pairings are right >= ``precision``."""
    order = np.argsort(-confidence, kind="stable")
    right = np.cumsum(correct[order]) / np.arange(1, len(order) + 1)
    ok = np.flatnonzero(right >= precision)
    if len(ok) == 0:
        return 1.0, float("nan"), 0.0
    k = ok.max()
    threshold = float(confidence[order][k])
    above = confidence >= threshold
    return threshold, float(correct[above].mean()), float(above.mean())
