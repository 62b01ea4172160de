"""The error budget's report: the terminal table, the markdown report with every magnitude's citation, the tornado
chart, and the comparison with the phantom (thesis §5.1, Fig. 16).

Why: the reader's questions are "which source dominates, what would the total be without it, and is the phantom's
8.9 mm what this set-up should give?"; the report answers them in that order and says how each source was run.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from snreg.demo.errors import PARAMETERS
from snreg.files import atomic_write
from snreg.simulation.budget import BudgetResult

__all__ = ["format_table", "markdown_report", "write_budget_report", "plot_tornado", "phantom_gap", "coverage_line",
           "PHANTOM_RMS_MM", "PHANTOM_RANGE_MM"]

PHANTOM_RMS_MM = (8.9, 11.4)            # thesis §5.1, Fig. 16: the two tries' RMS
PHANTOM_RANGE_MM = (8.9 - 3.3, 11.4 + 1.6)   # both tries' mean -+ sd


def _row(name: str, figure) -> str:
    def q(values, percent):
        values = values[np.isfinite(values)]
        return f"{np.percentile(values, percent):5.2f}" if len(values) else "  -  "

    coverage = figure.coverage_90
    covered = f"{100 * coverage:5.1f}%" if np.isfinite(coverage) else "   -  "
    return (f"| {name:<22} | {q(figure.rms_mm, 50)} | {q(figure.rms_mm, 90)} | {q(figure.node_error_mm, 50)} "
            f"| {q(figure.node_error_mm, 90)} | {100 * np.mean(figure.paired):5.1f}% | {covered} |")


def format_table(result: BudgetResult) -> str:
    """Markdown table: all sources, each alone, all but each, none (the registration's own floor); coverage: the
    share of nodes inside their own 90 % ellipsoid ("-" where no source gives the nodes a full ellipsoid)."""
    lines = ["| configuration          | RMS median (mm) | RMS p90 | node error median (mm) | node p90 | pairing "
             "| coverage 90% |", "|---|---|---|---|---|---|---|", _row("all sources", result.figures["all"])]
    order = sorted(result.sources, key=lambda s: result.figures[f"all_but:{s}"].rms_median)
    for source in order:
        lines.append(_row(f"{source} alone", result.figures[f"alone:{source}"]))
    for source in order:
        lines.append(_row(f"all but {source}", result.figures[f"all_but:{source}"]))
    lines.append(_row("none (registration)", result.figures["none"]))
    return "\n".join(lines)


def coverage_line(result: BudgetResult) -> str:
    """One sentence: how often the nodes' own 90 % ellipsoids held their intraop error (all sources), and whether the
    registration was given the covariances."""
    coverage = result.figures["all"].coverage_90
    held = "no node has an ellipsoid (no intraop error source)" if not np.isfinite(coverage) else \
        f"the nodes' own 90 % ellipsoids held their intraop error for {100 * coverage:.1f}% of nodes"
    given = "registered with" if result.config.covariances else "registered without"
    return f"Each node's covariance (all sources): {held}; {given} the covariances."


def phantom_gap(result: BudgetResult) -> list[str]:
    """Sentences: where the total lies against the phantom's range, and per source the factor by which it alone would
    have to grow to reach the phantom's 8.9 mm and the range's low end (quadrature estimate, ``--set SOURCE=F``)."""
    total = result.figures["all"].rms_median
    low, high = PHANTOM_RANGE_MM
    if low <= total <= high:
        where = f"lies within the phantom's spread {low:.1f}-{high:.1f} mm"
    elif total < low:
        where = f"lies {low - total:.1f} mm below the phantom's spread {low:.1f}-{high:.1f} mm"
    else:
        where = f"lies {total - high:.1f} mm above the phantom's spread {low:.1f}-{high:.1f} mm"
    lines = [f"The budget's median RMS, {total:.2f} mm, {where} (thesis Fig. 16: {PHANTOM_RMS_MM[0]} and "
             f"{PHANTOM_RMS_MM[1]} mm)."]
    if low <= total <= high:
        return lines
    lines.append("To explain the phantom by one source alone (its error scaled by F, the others as they are; "
                 "estimated in quadrature from the all and all-but figures; check with --set SOURCE=F):")
    for source in result.sources:
        without = result.figures[f"all_but:{source}"].rms_median
        share = np.sqrt(max(total**2 - without**2, 0.0))
        targets = []
        for target in (low, PHANTOM_RMS_MM[0]):
            need = np.sqrt(max(target**2 - without**2, 0.0))
            targets.append("never" if share < 0.05 * total else
                           ("x0" if need == 0 else f"x{need / share:.1f}") + f" for {target:.1f} mm")
        lines.append(f"- {source}: {', '.join(targets)}")
    return lines


def markdown_report(result: BudgetResult, command: str = "", seconds: float = float("nan")) -> str:
    """The report: settings, table, dominant source, the prediction, additivity, the phantom, magnitudes cited."""
    figures, model = result.figures, result.model
    total = figures["all"].rms_median
    dominant = result.dominant
    lines = [f"# Error budget: {model.name}", ""]
    if command:
        lines += [f"`{command}`", ""]
    with_cov = " with each node's covariance" if result.config.covariances else ""
    lines += [f"Error model {model.path or model.name}; {result.config.reps} repetitions, seed {result.config.seed}, "
              f"registration {result.config.method}{with_cov} from the operator's rough alignment; "
              f"{result.config.draws} "
              f"rendered-tracking draws and {result.config.imu_draws} fused IMU sessions shared by the repetitions"
              + (f"; {seconds:.0f} s." if np.isfinite(seconds) else "."), "", format_table(result), ""]
    if dominant:
        lines += [f"**Dominant source: {dominant}.** Without it the median RMS would be "
                  f"{figures[f'all_but:{dominant}'].rms_median:.2f} mm instead of {total:.2f} mm.", ""]
    squares = sum(figures[f"alone:{s}"].rms_median ** 2 for s in result.sources)
    lines += [f"Additivity: the single-source medians add in quadrature to {np.sqrt(squares):.2f} mm against "
              f"{total:.2f} mm for all together ({100 * (squares / total**2 - 1):+.0f}% in squares). Sources "
              "interact where one only shows through another: an IMU turn error or a chain distance moves nodes only "
              "when the camera turned, a camera turn costs nothing by itself.", "",
              coverage_line(result), "", "## Prediction beside the simulation", "",
              f"Node error (FLE, RMS over nodes and repetitions, all sources): {result.fle_mm:.2f} mm. Fitzpatrick and "
              f"West, for a least-squares rigid fit of {_nodes(result)}: TRE at the nodes "
              f"{result.tre_predicted_mm:.2f} mm RMS, RMS after registration (FRE) {result.fre_predicted_mm:.2f} mm. "
              f"Monte Carlo ({result.config.method}): TRE {result.tre_mc_mm:.2f} mm RMS, RMS median {total:.2f} mm. "
              f"Of the node error, a median {np.median(figures['all'].common_mm):.2f} mm is common to all nodes (a "
              "shift: it adds to the TRE but never to the RMS). A gap between the two says the errors are not "
              "independent and isotropic, or the method is not a least-squares fit (chamfer's step sizes).", "",
              "## Against the phantom", ""] + (phantom_gap(result) if not result.config.cohort else
                                                 [f"Run over {len(result.config.cohort)} patient-like node sets "
                                                  "(--cohort), not the phantom: no comparison."])
    lines += ["", "## Magnitudes and where they come from", ""]
    for source in result.sources:
        factor = model.on(source)
        lines.append(f"- **{source}** ({result.paths.get(source, '')})" + (f", scaled x{factor:g}" if factor != 1 else ""))
        for name, spec in PARAMETERS[source].items():
            value = model.values[source][name]
            cite = model.cite(source, name) or "(no citation given)"
            lines.append(f"  - {name} = {value}{(' ' + spec.unit) if spec.unit else ''}: {cite}")
    off = [s for s in PARAMETERS if not model.on(s)]
    if off:
        lines += ["", f"Switched off: {', '.join(off)}."]
    refused = {name: f.failed for name, f in figures.items() if f.failed}
    if refused:
        lines += ["", "Registrations refused (no pairing within the bounds; counted as wrongly paired, left out of the "
                  "RMS): " + ", ".join(f"{name} {count}" for name, count in refused.items()) + "."]
    if result.lost_frames:
        lines += ["", f"{result.lost_frames} rendered frames gave no fix (their nodes took the median of the rest)."]
    return "\n".join(lines) + "\n"


def _nodes(result: BudgetResult) -> str:
    if result.config.cohort:
        return "each patient's nodes"
    figure = result.figures["all"]
    return f"these {len(figure.node_error_mm) // len(figure.rms_mm)} nodes"


def plot_tornado(result: BudgetResult, path: str | Path) -> Path:
    """A tornado chart (PNG): per source, the median RMS without it (bar from there to all sources), largest on top,
    with its RMS alone as a dot; the phantom's spread shaded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    total = result.figures["all"].rms_median
    order = sorted(result.sources, key=lambda s: result.figures[f"all_but:{s}"].rms_median, reverse=True)
    fig, ax = plt.subplots(figsize=(8, 0.5 * len(order) + 2.4), dpi=110)
    low, high = PHANTOM_RANGE_MM
    ax.axvspan(low, high, color="0.9", zorder=0)
    for value in PHANTOM_RMS_MM:
        ax.axvline(value, color="0.6", linestyle=":", zorder=1)
    for y, source in enumerate(order):
        without = result.figures[f"all_but:{source}"].rms_median
        alone = result.figures[f"alone:{source}"].rms_median
        ax.barh(y, total - without, left=without, color="tab:red", height=0.6, zorder=2,
                label="saved by removing it" if y == len(order) - 1 else None)
        ax.plot([alone], [y], "o", color="tab:blue", zorder=3, label="the source alone" if y == len(order) - 1 else None)
    ax.axvline(total, color="black", zorder=3, label=f"all sources: {total:.1f} mm")
    ax.axvspan(0, 0, color="0.9", label=f"phantom {low:.1f}-{high:.1f} mm (thesis Fig. 16)")
    ax.set_yticks(range(len(order)), order)
    ax.set_xlabel(f"registration RMS, median over {result.config.reps} repetitions ({result.config.method}), mm")
    ax.set_xlim(0, max(high, total) * 1.05)
    ax.set_title(f"Error budget: {result.model.name}", loc="left")
    ax.legend(loc="lower right", fontsize=8, framealpha=0.95)
    fig.tight_layout()
    path = Path(path)
    with atomic_write(path) as temporary:
        fig.savefig(temporary, format="png")
    plt.close(fig)
    return path


def write_budget_report(result: BudgetResult, folder: str | Path, command: str = "",
                        seconds: float = float("nan")) -> dict[str, Path]:
    """``budget.md``, ``tornado.png`` and ``budget.json`` in ``folder`` (created)."""
    import json

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = {"markdown": folder / "budget.md", "tornado": folder / "tornado.png", "json": folder / "budget.json"}
    with atomic_write(paths["markdown"]) as temporary:
        temporary.write_text(markdown_report(result, command, seconds), encoding="utf-8")
    with atomic_write(paths["json"]) as temporary:
        temporary.write_text(json.dumps(result.to_json(), indent=1) + "\n", encoding="utf-8")
    plot_tornado(result, paths["tornado"])
    return paths
