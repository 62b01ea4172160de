"""The study report: markdown tables (thesis Tables 6-8, Fig. 23 analogues), a trial CSV and PNG plots."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from snreg.files import atomic_write
from snreg.registration import CONFIDENT
from snreg.simulation.stats import accuracy, calibration, column, extras_breakdown, paired_tests, select, threshold_for
from snreg.simulation.study import StudyResult

__all__ = ["markdown_report", "write_report", "table6", "missing_table", "claims_table", "coverage_table",
           "incremental_table", "landmarks_table"]

ORACLES = ("oracle_nearest", "oracle_one_to_one")


def _table(header: list[str], lines: list[list[str]]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(line) + " |" for line in lines]
    return "\n".join(out)


def _pm(values: np.ndarray) -> str:
    return f"{values.mean():.1f} ± {values.std(ddof=1) if len(values) > 1 else 0.0:.1f}"


def table6(study: StudyResult) -> str:
    """The thesis' protocol: every preop node present intraop (trials with missing nodes are in :func:`missing_table`)."""
    methods = list(study.config.methods)
    protocol = select(study.rows, n_missing=0)
    oracles_shown = ORACLES + (("oracle_nearest_cov",) if study.config.anisotropy != 1.0 else ())
    header = (["sigma (mm)", "trials", "avg max error (mm)", "avg error (mm)", "oracle NN", "oracle 1-1"]
              + (["oracle NN (cov)"] if len(oracles_shown) > 2 else []) + methods)
    best = "global" if "global" in methods else methods[-1]
    header.append(f"{best} - best oracle (pp)")
    lines = []
    for sigma in study.config.sigmas:
        rows = select(protocol, sigma=sigma, method=methods[0])
        if not rows:
            continue
        oracles = [accuracy(column(rows, o)) for o in oracles_shown]
        accs = [accuracy(column(select(protocol, sigma=sigma, method=m), "success")) for m in methods]
        gap = 100 * (accs[methods.index(best)].rate - max(o.rate for o in oracles))
        lines.append([f"{sigma:g}", str(len(rows)), _pm(column(rows, "max_error_mm")), _pm(column(rows, "mean_error_mm"))]
                     + [str(o) for o in oracles] + [str(a) for a in accs] + [f"{gap:+.1f}"])
    return _table(header, lines)


def table8(study: StudyResult) -> str:
    methods = list(study.config.methods)
    header = ["sigma (mm)"] + [f"{m} RMS (mm)" for m in methods] + [f"{m} TRE (mm)" for m in methods] + [f"{m} ms" for m in methods]
    lines = []
    for sigma in study.config.sigmas:
        subsets = [select(study.rows, sigma=sigma, method=m) for m in methods]
        lines.append([f"{sigma:g}"] + [_pm(column(s, "rms_mm")) for s in subsets]
                     + [_pm(column(s, "tre_mm")) for s in subsets]
                     + [f"{np.median(column(s, 'time_ms')):.1f}" for s in subsets])
    return _table(header, lines)


def comparisons(study: StudyResult) -> str:
    methods = list(study.config.methods)
    header = ["sigma (mm)", "a vs b", "mean RMS a / b", "t-test p (Bonferroni)", "only a right / only b right", "McNemar p (Bonferroni)"]
    lines = []
    for sigma in study.config.sigmas:
        for test in paired_tests(select(study.rows, sigma=sigma), methods):
            lines.append([f"{sigma:g}", f"{test['a']} vs {test['b']}", f"{test['rms_a']:.2f} / {test['rms_b']:.2f}",
                          f"{test['t_p_bonferroni']:.3g}", f"{test['only_a']} / {test['only_b']}",
                          f"{test['mcnemar_p_bonferroni']:.3g}"])
    return _table(header, lines)


def table7(study: StudyResult) -> str:
    extras = list(study.config.extras)
    header = ["method", "sigma (mm)"] + [f"{e} extra: RMS, p vs {extras[0]}, accuracy" for e in extras]
    lines = []
    for method in study.config.methods:
        for sigma in study.config.sigmas:
            cells = []
            for item in extras_breakdown(select(study.rows, sigma=sigma), method, extras):
                p = "" if np.isnan(item["p_vs_first"]) else f", p={item['p_vs_first']:.3g}"
                cells.append(f"{item['rms_mean']:.1f}±{item['rms_std']:.1f}{p}, {100 * item['accuracy'].rate:.0f}%")
            lines.append([method, f"{sigma:g}"] + cells)
    return _table(header, lines)


def error_ratio(study: StudyResult) -> str:
    header = ["method", "sigma (mm)", "max ratio, right: median [max]", "max ratio, wrong: median [min]"]
    lines = []
    for method in study.config.methods:
        for sigma in study.config.sigmas:
            rows = select(study.rows, sigma=sigma, method=method)
            ratio, ok = column(rows, "max_error_ratio"), column(rows, "success").astype(bool)
            right = f"{np.median(ratio[ok]):.2f} [{ratio[ok].max():.2f}]" if ok.any() else "-"
            wrong = f"{np.median(ratio[~ok]):.2f} [{ratio[~ok].min():.2f}]" if (~ok).any() else "-"
            lines.append([method, f"{sigma:g}", right, wrong])
    return _table(header, lines)


def calibration_table(study: StudyResult) -> str:
    header = ["method", f"pairings >= {CONFIDENT}: right", "coverage", "threshold for 99% right", "bins: [lo, hi) n right"]
    lines = []
    for method in study.config.methods:
        conf, corr = study.confidence[method], study.correct[method]
        above = conf >= CONFIDENT
        thr, _, cover = threshold_for(conf, corr)
        bins = "; ".join(f"[{b['low']:.2f},{b['high']:.2f}) {b['n']} {100 * b['right']:.1f}%" for b in calibration(conf, corr))
        right = f"{100 * corr[above].mean():.2f}% of {int(above.sum())}" if above.any() else "-"
        lines.append([method, right, f"{100 * above.mean():.1f}%", f"{thr:.3f} (covers {100 * cover:.1f}%)", bins])
    return _table(header, lines)


def _rate(rows: list[dict], key: str) -> str:
    return f"{100 * column(rows, key).mean():.1f}" if rows else "-"


def missing_table(study: StudyResult) -> str:
    """Per sigma and number of SPECT nodes left out: true-node accuracy / all-claims accuracy (an extra is right with
    its host's hot spot or -1) of every method, the true-transform oracles, and global's transform under the thesis'
    nearest rule (the simple rule on the same fit)."""
    methods = list(study.config.methods)
    nearest = [m for m in methods if m.startswith("global")]
    header = (["sigma (mm)", "missing", "trials", "oracle NN", "oracle model"] + methods
              + [f"{m} (nearest)" for m in nearest])
    lines = []
    for sigma in study.config.sigmas:
        for n_missing in study.config.missing:
            rows = select(study.rows, sigma=sigma, n_missing=n_missing, method=methods[0])
            if not rows:
                continue
            cells = [f"{_rate(rows, 'oracle_nearest')} / {_rate(rows, 'oracle_nearest_all_claims')}",
                     _rate(rows, "oracle_model")]
            for m in methods:
                own = select(study.rows, sigma=sigma, n_missing=n_missing, method=m)
                cells.append(f"{_rate(own, 'success')} / {_rate(own, 'all_claims')}")
            for m in nearest:
                own = select(study.rows, sigma=sigma, n_missing=n_missing, method=m)
                cells.append(f"{_rate(own, 'success_nearest')} / {_rate(own, 'all_claims_nearest')}")
            lines.append([f"{sigma:g}", str(n_missing), str(len(rows))] + cells)
    return _table(header, lines)


def claims_table(study: StudyResult) -> str:
    """Every intraop node's claim (a hot spot, or -1) by number of missing SPECT nodes: how many are confident (all
    sigmas, and sigma <= 5 mm) and how often a confident claim is right, extras included."""
    header = ["method", "missing", "claims", f"confident (>= {CONFIDENT})", "confident at sigma <= 5 mm",
              "confident right", "confident wrong: extras / true nodes"]
    lines = []
    for method in study.config.methods:
        claims = study.claims[method]
        for n_missing in study.config.missing:
            sel = claims["n_missing"] == n_missing
            confident = sel & (claims["confidence"] >= CONFIDENT)
            low = sel & (claims["sigma"] <= 5.0)
            wrong = confident & ~claims["correct"]
            right = f"{100 * claims['correct'][confident].mean():.2f}%" if confident.any() else "-"
            low_share = f"{100 * (confident & low).sum() / low.sum():.1f}%" if low.any() else "-"
            lines.append([method, str(n_missing), str(int(sel.sum())),
                          f"{int(confident.sum())} ({100 * confident.sum() / max(sel.sum(), 1):.1f}%)", low_share,
                          right, f"{int((wrong & claims['extra']).sum())} / {int((wrong & ~claims['extra']).sum())}"])
    return _table(header, lines)


def coverage_table(study: StudyResult) -> str:
    """Left-out SPECT nodes: how often the reported 90% target-error bound covers the distance between the node's
    mapped position and where it really is (a refused registration counts as not covered)."""
    header = ["method", "sigma (mm)", "left-out nodes", "covered by the 90% bound", "median bound (mm)",
              "median error (mm)", "bound / error"]
    lines = []
    for method in study.config.methods:
        bounds = study.bounds[method]
        for sigma in study.config.sigmas:
            sel = bounds["sigma"] == sigma
            if not sel.any():
                continue
            bound, error = bounds["bound_mm"][sel], bounds["error_mm"][sel]
            covered = np.nan_to_num(error, nan=np.inf) <= bound
            median_bound, median_error = np.median(bound[np.isfinite(bound)]), np.nanmedian(error)
            lines.append([method, f"{sigma:g}", str(int(sel.sum())), f"{100 * covered.mean():.1f}%",
                          f"{median_bound:.1f}", f"{median_error:.1f}", f"{median_bound / median_error:.2f}"])
    return _table(header, lines)


def incremental_table(study: StudyResult) -> str:
    """Nodes stored one by one, registered after each store from the third on: how often the stored true nodes are
    all paired right, and every stored node's claim is right, by the number stored so far."""
    header = ["method", "stored", "registrations", "stored true nodes all right", "every claim right"]
    lines = []
    for method in study.config.methods:
        rows = [r for r in study.incremental if r["method"] == method]
        for stored in sorted({r["stored"] for r in rows}):
            at = [r for r in rows if r["stored"] == stored]
            lines.append([method, str(stored), str(len(at)), str(accuracy(column(at, "success"))),
                          str(accuracy(column(at, "all_claims_right")))])
    return _table(header, lines)


def landmarks_table(study: StudyResult) -> str:
    """Per sigma and method: pairing success, the share of trials with a landmark flagged (and the swapped ones)."""
    methods = list(study.config.methods)
    swap = study.config.swap_landmarks
    header = ["sigma (mm)"] + [f"{m}: success / flagged" + (" / swapped flagged" if swap else "") for m in methods]
    lines = []
    for sigma in study.config.sigmas:
        cells = []
        for m in methods:
            rows = select(study.rows, sigma=sigma, method=m)
            if not rows:
                cells.append("")
                continue
            cell = f"{_rate(rows, 'success')} / {_rate(rows, 'landmarks_flagged')}"
            cells.append(cell + (f" / {_rate(rows, 'swapped_flagged')}" if swap else ""))
        lines.append([f"{sigma:g}"] + cells)
    return _table(header, lines)


def markdown_report(study: StudyResult, command: str = "") -> str:
    cfg = study.config
    parts = [
        "# snreg simulation study",
        f"`{command}`" if command else "",
        f"Methods {', '.join(cfg.methods)}; sigma {', '.join(f'{s:g}' for s in cfg.sigmas)} mm; extras "
        f"{', '.join(map(str, cfg.extras))}; SPECT nodes missing {', '.join(map(str, cfg.missing))}; "
        f"{cfg.reps} repetitions per patient and condition; seed {cfg.seed}.",
        "## Pairing accuracy (Table 6 analogue)",
        "Every true intraop node claims its own hot spot (preop node); 95% Wilson intervals. Oracles use the true "
        "transform.",
        table6(study),
        "## RMS after registration (Table 8 analogue), TRE and median time",
        table8(study),
        "## Paired comparisons",
        comparisons(study),
        "## By number of extra nodes (Table 7 analogue)",
        table7(study),
        "## Max error ratio (Fig. 23 analogue)",
        error_ratio(study),
        "## Confidence calibration (true intraop nodes)",
        calibration_table(study),
        "## Claims of every intraop node, extras included",
        claims_table(study),
    ]
    if study.config.landmarks:
        parts += ["## Anatomical landmarks",
                  f"{cfg.landmarks} landmark pairs per trial, {cfg.landmark_sd:g} mm per axis each"
                  + (f"; patients cut to {cfg.max_nodes} SPECT nodes" if cfg.max_nodes else "")
                  + ("; the first two landmarks' names exchanged intraop" if cfg.swap_landmarks else "") + ". "
                  "Success as above; flagged: any landmark pair in landmarks_suspect"
                  + ("; swapped flagged: one of the two exchanged ones" if cfg.swap_landmarks else "") + ".",
                  landmarks_table(study)]
    if study.config.incremental:
        parts += [
            "## With SPECT nodes not found (missing)",
            "Each cell: true-node accuracy (every remaining true intraop node claims its own hot spot) / all-claims "
            "accuracy (also every extra claims its host's hot spot or -1), %. Oracles use the true transform: NN, "
            "the thesis' nearest rule; model, global's hot-spot labelling at the true transform and sigma. "
            "\"(nearest)\": global's own transform under the nearest rule.",
            missing_table(study),
            "## Where the missing nodes are: target-error bound coverage",
            coverage_table(study),
            "## Incremental: registering after each store",
            incremental_table(study),
        ]
    return "\n\n".join(p for p in parts if p) + "\n"


def write_report(study: StudyResult, directory: str | Path, command: str = "") -> dict[str, Path]:
    """Write report.md, trials.csv and the PNG plots into ``directory`` (each atomically); returns their paths."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    paths = {"markdown": directory / "report.md", "trials": directory / "trials.csv"}
    with atomic_write(paths["markdown"]) as temporary:
        temporary.write_text(markdown_report(study, command), encoding="utf-8")
    with atomic_write(paths["trials"]) as temporary, temporary.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(study.rows[0]))
        writer.writeheader()
        writer.writerows(study.rows)
    paths.update(_plots(study, directory))
    return paths


def _plots(study: StudyResult, directory: Path) -> dict[str, Path]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cfg = study.config
    sigmas = np.array(cfg.sigmas)
    out = {}

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for name in list(ORACLES) + list(cfg.methods):
        key, method = (name, cfg.methods[0]) if name in ORACLES else ("success", name)
        accs = [accuracy(column(select(study.rows, sigma=s, method=method), key)) for s in cfg.sigmas]
        rate = np.array([a.rate for a in accs]) * 100
        err = np.array([[a.rate - a.low, a.high - a.rate] for a in accs]).T * 100
        ax.errorbar(sigmas, rate, yerr=err, marker="o", capsize=3, label=name, linestyle="--" if name in ORACLES else "-")
    ax.set(xlabel="intraop error sigma per axis (mm)", ylabel="pairing accuracy (%)", title="Pairing accuracy (95% CI)")
    ax.legend()
    ax.grid(alpha=0.3)
    out["accuracy_plot"] = directory / "accuracy.png"
    _save(fig, out["accuracy_plot"])
    plt.close(fig)

    fig, axes = plt.subplots(1, len(cfg.methods), figsize=(3.2 * len(cfg.methods), 4), sharey=True, squeeze=False)
    for ax, method in zip(axes[0], cfg.methods):
        data, labels = [], []
        for s in cfg.sigmas:
            rows = select(study.rows, sigma=s, method=method)
            ratio, ok = column(rows, "max_error_ratio"), column(rows, "success").astype(bool)
            data += [ratio[ok], ratio[~ok]]
            labels += [f"{s:g}✓", f"{s:g}✗"]
        ax.boxplot([d if len(d) else [np.nan] for d in data], showfliers=False)
        ax.set_xticks(range(1, len(labels) + 1), labels, rotation=90, fontsize=7)
        ax.axhline(1.0, color="grey", lw=0.8)
        ax.set_title(method)
    axes[0][0].set_ylabel("max error ratio (Fig. 23)")
    out["error_ratio_plot"] = directory / "error_ratio.png"
    _save(fig, out["error_ratio_plot"])
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(5, 5))
    for method in cfg.methods:
        bins = calibration(study.confidence[method], study.correct[method])
        ax.plot([b["mean_confidence"] for b in bins], [b["right"] for b in bins], marker="o", label=method)
    ax.plot([0, 1], [0, 1], color="grey", lw=0.8)
    ax.set(xlabel="confidence", ylabel="fraction of pairings right", title="Confidence calibration")
    ax.legend()
    out["calibration_plot"] = directory / "calibration.png"
    _save(fig, out["calibration_plot"])
    plt.close(fig)
    return out


def _save(figure, path: Path) -> None:
    """Save a matplotlib figure as PNG atomically."""
    with atomic_write(path) as temporary:
        figure.savefig(temporary, dpi=120, bbox_inches="tight", format="png")
