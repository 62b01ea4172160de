"""How a registration is said to a technician: one rule for confidence, for what was used, for leave-one-out.

Why (issue 35): the headless demo printed 0.997 where ``snreg register`` printed 0.94 on the same files, a 0.947
read "0.95 (check)", a 0.9996 read "1.000", "(check)" did not say what to check, and neither output said that one
used the L/R labels and the other each node's covariance. Every screen and file (the registration panel, ``snreg
register``, the headless demo, the pairing CSV and the PNG report) takes its words and digits from here:

- a confidence is cut, never rounded up (:func:`confidence_text`, :func:`confidence_value`): the digits lie on the
  same side of ``CONFIDENT`` as the value, and read 1.00 only for a certain claim;
- a doubtful claim says what to do (:data:`CHECK_WORDS`);
- every output names what the registration used and what it did not, and why (:class:`UsedInputs`);
- a leave-one-out distance stands beside what it would be for a right pair (:func:`loo_text`);
- the internal names (the pairing rule, gravity's two directions) are said in plain words.

>>> confidence_text(0.947), confidence_text(0.9999), confidence_text(1.0)
('0.94', '0.99', '1.00')
>>> used_inputs(result, labels=True, intraop_cov=True, preop_cov=True).text()
"used: labels (left/right, station), each stored node's and each hot spot's own error (covariance); not used: ..."
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from decimal import ROUND_FLOOR, Decimal

from snreg.registration import CONFIDENT

__all__ = ["confidence_text", "confidence_value", "CHECK_WORDS", "check_words", "UsedInputs", "used_inputs",
           "labels_given", "loo_text", "LOO_LEGEND", "PAIRING_RULE_WORDS", "rule_words", "down_words",
           "HOT_SPOT_LEGEND"]

CHECK_WORDS = f"below {CONFIDENT:g}: confirm this node's label or store it again"
HOT_SPOT_LEGEND = ("hot spot: the SPECT node a removed node came from (several may share one: 'with'; none: from no "
                   "imaged hot spot)")
LOO_LEGEND = ("loo: the node's distance from its hot spot when the other pairs alone register; beside it, what it "
              "would be for a right pair (typical, and the 90 % bound from the registration's own error model): a "
              "loo beyond its bound flags a suspect node")
PAIRING_RULE_WORDS = {
    "hot_spot": "each node paired with the hot spot it most probably came from (none when it lies beyond every one)",
    "nearest": "each node paired with the nearest hot spot (the thesis' rule)",
    "one_to_one": "at most one node per hot spot, the nearest assignment",
}


def confidence_value(confidence: float, decimals: int = 4) -> float:
    """``confidence`` cut (rounded down) to ``decimals`` places, for JSON and CSV: 0.94999 is 0.9499, never 0.95 beside
    ``"confident": false``; 1.0 only for 1. NaN stays NaN."""
    if math.isnan(confidence):
        return confidence
    step = Decimal(1).scaleb(-decimals)
    return float(Decimal(repr(float(confidence))).quantize(step, rounding=ROUND_FLOOR))


def confidence_text(confidence: float, decimals: int = 2) -> str:
    """A claim's confidence for screens, cut to ``decimals`` places (two): what is printed lies on the same side of
    ``CONFIDENT`` as the value (0.9496 reads 0.94, 0.95 reads 0.95) and reads 1.00 only when the value is 1 (0.9999
    reads 0.99)."""
    return f"{confidence_value(confidence, decimals):.{decimals}f}"


def check_words(confidence: float) -> str:
    """"" for a confident claim, else "(below 0.95: confirm this node's label or store it again)"."""
    return "" if confidence >= CONFIDENT else f"({CHECK_WORDS})"


def labels_given(labels) -> bool:
    """Do ``labels`` (a list of str, or None) name anything: not None and not all empty?"""
    return labels is not None and any(str(label).strip() for label in labels)


@dataclass(frozen=True)
class UsedInputs:
    """What a registration was given besides the positions, with why each absent one was not: ``labels`` (L/R and
    station, forbidding left/right crossings), ``landmark_pairs`` (paired by name) of which ``landmarks_suspect`` were
    left out, each side's own covariances; the ``*_why`` say why one was not used ("" when it was)."""

    labels: bool
    landmark_pairs: int
    intraop_cov: bool
    preop_cov: bool
    labels_why: str = "none given"
    landmarks_why: str = "none given"
    cov_why: str = "not given"
    landmarks_suspect: int = 0

    def _parts(self) -> tuple[list[str], list[str]]:
        used, unused = [], []
        (used if self.labels else unused).append("labels (left/right, station)" if self.labels
                                                  else f"labels ({self.labels_why})")
        if self.landmark_pairs:
            out = f", {self.landmarks_suspect} left out as suspect" if self.landmarks_suspect else ""
            used.append(f"{self.landmark_pairs} landmark pair{'s' * (self.landmark_pairs > 1)}{out}")
        else:
            unused.append(f"landmarks ({self.landmarks_why})")
        sides = [w for w, on in (("each stored node's", self.intraop_cov), ("each hot spot's", self.preop_cov)) if on]
        if sides:
            used.append(f"{' and '.join(sides)} own error (covariance)")
        if not (self.intraop_cov and self.preop_cov):
            whose = ("the hot spots'" if self.intraop_cov else "the stored nodes'" if self.preop_cov
                     else "the nodes' own errors")
            unused.append(f"{whose} covariances ({self.cov_why})" if sides
                          else f"{whose} (covariances: {self.cov_why})")
        return used, unused

    def text(self) -> str:
        """One line: ``"used: labels (left/right, station), 3 landmark pairs, ...; not used: ..."``."""
        used, unused = self._parts()
        return "; ".join(part for part in (f"used: {', '.join(used)}" if used else "used: the positions alone",
                                           f"not used: {', '.join(unused)}" if unused else "") if part)

    def as_json(self) -> dict:
        return {"labels": self.labels, "landmark_pairs": self.landmark_pairs,
                "landmarks_suspect": self.landmarks_suspect,
                "intraop_covariances": self.intraop_cov, "preop_covariances": self.preop_cov, "words": self.text()}


def used_inputs(result, *, labels: bool, intraop_cov: bool, preop_cov: bool, labels_why: str = "none given",
                landmarks_why: str = "none given", cov_why: str = "not given") -> UsedInputs:
    """:class:`UsedInputs` of a :class:`~snreg.registration.RegistrationResult` registered with (``labels``) or without
    labels and with each side's covariances or not; its landmark pairs come from the result itself."""
    pairs = len(result.landmark_residual_mm or {})
    return UsedInputs(bool(labels), pairs, bool(intraop_cov), bool(preop_cov), labels_why, landmarks_why, cov_why,
                      len(result.landmarks_suspect or ()))


def loo_text(loo_mm: float, typical_mm: float, bound_mm: float) -> str:
    """A leave-one-out distance beside a right pair's: ``"19.2 (right: ~15, <= 27)"``, with ``" SUSPECT"`` beyond the
    bound; "" for a node from no hot spot, the distance alone without an expectation."""
    if math.isnan(loo_mm):
        return ""
    if math.isnan(bound_mm):
        return f"{loo_mm:.1f}"
    return f"{loo_mm:.1f} (right: ~{typical_mm:.0f}, <= {bound_mm:.0f})" + (" SUSPECT" if loo_mm > bound_mm else "")


def rule_words(rule: str) -> str:
    """The pairing rule in plain words (the rule's name itself when unknown)."""
    return PAIRING_RULE_WORDS.get(rule, rule)


def down_words(side: str) -> str:
    """Gravity's direction on one side, in words: "preop" (the SPECT/CT's patient frame, LPS) or "intraop" (the
    trocar frame, at the endoscope)."""
    return {"preop": "gravity in the SPECT/CT (patient frame, LPS)",
            "intraop": "gravity at the endoscope (trocar frame)"}[side]
