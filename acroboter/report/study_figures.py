"""The studies' figures (matplotlib, written as PNG without a display).

- `sweep_figures`: a penalty-number grid's rows (acroboter.studies.penalty_grid.COLUMNS) against the swept α:
  tracking error, constraint violation and cond(A), a panel per method and a line per Ω;
- `position_error_figure`: the position error over time of a study's runs (acroboter.studies.formulations), one
  line per case.

matplotlib is imported inside the functions: the CLIs' --help and --no-plots never load it.
"""

from __future__ import annotations

from pathlib import Path

from ..studies.penalty_grid import x_key, x_label
from ..studies.run_verdicts import mlm_row, ok, penalty_methods


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")  # files only: no display on a cluster node or in CI
    import matplotlib.pyplot as plt

    return plt


SWEEP_FIGURES = [  # file, title, (column, y label) per row of panels
    ("sweep_tracking_error.png", "Max position error against the penalty numbers (MLM: no penalty numbers; "
                                 "dotted: {tolerance:g}x MLM)",
     [("max_position_error_mm", "max |r_SU − r_d| (mm)")]),
    ("sweep_constraints.png", "Constraint violation: the commanded q̈ (what α controls) and the plant (truth)",
     [("max_constraint_accel_residual", "controller max |φ_q q̈ + ρ|"),
      ("max_servo_accel_residual", "controller max |σ_q q̈ + ρ_s|"),
      ("max_constraint_violation", "plant max |φ|")]),
    ("sweep_condition.png", "Condition number of A = M + α̃ φ_qᵀφ_q + α̂ σ_qᵀσ_q (max over states along the run; "
                            "open: at the start, run did not finish)",
     [("cond_penalty_matrix", "cond(A)")]),
]


def sweep_figures(out: Path, rows: list[dict], alpha_mode: str = "tied", tolerance: float = 2.0) -> list[Path]:
    """Tracking error, constraint violation and cond(A) against α: a panel per method, a line per Ω
    (per (Ω, α̂) in grid mode), MLM as a horizontal line; runs that did not finish as red crosses."""
    import numpy as np

    methods = penalty_methods(rows)
    if not methods:
        return []
    plt = _pyplot()
    xk = x_key(alpha_mode)
    ref = mlm_row(rows)
    omegas = sorted({r["omega"] for r in rows if r["method"] != "mlm"})
    servos = sorted({r["alpha_servo"] for r in rows if r["method"] != "mlm"}) if alpha_mode == "grid" else [None]
    cmap = plt.get_cmap("viridis")
    styles = ["-", "--", ":", "-."]

    def series(method: str):
        for si, aserv in enumerate(servos):
            for oi, omega in enumerate(omegas):
                sel = [r for r in rows if r["method"] == method and r["omega"] == omega
                       and (aserv is None or r["alpha_servo"] == aserv)]
                sel.sort(key=lambda r: r[xk])
                if not sel:
                    continue
                if alpha_mode == "grid":
                    color = cmap(si / max(len(servos) - 1, 1))
                    label, style = f"α̂ = {aserv:.0e}, Ω = {omega:g}", styles[oi % len(styles)]
                else:  # later Ω dashed and thinner: equal curves stay visible on top of each other
                    color, label = cmap(0.85 * oi / max(len(omegas) - 1, 1)), f"Ω = {omega:g} 1/s"
                    style = styles[oi % len(styles)]
                yield sel, color, label, style

    def value(r, key, any_status=False):
        v = r.get(key)
        good = any_status or ok(r)
        return v if good and v is not None and np.isfinite(v) and v > 0 else np.nan  # log axes: no 0, no NaN

    written = []
    ncol = len(methods)
    for name, title, quantities in SWEEP_FIGURES:
        nrow = len(quantities)
        fig, axes = plt.subplots(nrow, ncol, figsize=(3.3 * ncol + 0.9, 2.6 * nrow + 1.0), sharex=True,
                                 sharey="row", squeeze=False, layout="constrained")
        for qi, (key, ylabel) in enumerate(quantities):
            for mi, method in enumerate(methods):
                ax = axes[qi, mi]
                _sweep_panel(ax, list(series(method)), key, xk, value, ref, tolerance)
                if key == "max_constraint_violation" and mi == ncol - 1:
                    # the plant holds |φ| at round-off: show it against a few decades, not its jitter
                    lo, hi = ax.get_ylim()
                    ax.set_ylim(min(lo, hi / 1e3), max(hi, lo * 1e3))
                if qi == 0:
                    ax.set_title(method)
                if qi == nrow - 1:
                    ax.set_xlabel(x_label(alpha_mode))
                if mi == 0:
                    ax.set_ylabel(ylabel, fontsize=9)
        fig.suptitle(title.format(tolerance=tolerance), fontsize=10)
        _one_legend(fig, axes)
        fig.savefig(out / name, dpi=110)
        plt.close(fig)
        written.append(out / name)
    return written


def _sweep_panel(ax, series: list, key: str, xk: str, value, ref, tolerance: float) -> None:
    """One method's curves of one quantity against α: a line per series, the runs that did not finish as red
    crosses (and, for cond(A), at their start state), MLM's value (and the tolerance) as horizontal lines."""
    import numpy as np

    cond = key == "cond_penalty_matrix"
    failed_x = []
    for si, (sel, color, label, style) in enumerate(series):
        xs = np.array([r[xk] for r in sel])
        ys = np.array([value(r, key) for r in sel])
        lw = max(1.8 - 0.5 * si, 0.8)
        ax.loglog(xs, ys, style, color=color, marker="o", ms=4 - si * 0.8, lw=lw, label=label)
        if cond:  # cond(A) at the start state for the runs that did not finish
            bad = [r for r in sel if not ok(r)]
            ax.loglog([r[xk] for r in bad], [value(r, key, True) for r in bad], "o", mfc="none",
                      color=color, ms=5)
        failed_x += [r[xk] for r in sel if not ok(r)]
    if cond:
        ax.axhline(1 / np.finfo(float).eps, color="gray", lw=1, ls="--", label="1/eps")
    elif ref is not None and ok(ref):
        v = value(ref, key)
        if np.isfinite(v):
            ax.axhline(v, color="crimson", lw=1.2, label="MLM")
            if key == "max_position_error_mm":
                ax.axhline(tolerance * v, color="crimson", lw=0.8, ls=":", label=f"{tolerance:g}x MLM")
    if failed_x:
        ax.plot(failed_x, [0.03] * len(failed_x), "x", color="red", ms=7, mew=2,
                transform=ax.get_xaxis_transform(), label="diverged / error", clip_on=False)
    ax.grid(True, which="major", alpha=0.3)


def _one_legend(fig, axes) -> None:
    """One legend entry per label over all panels, below them."""
    seen: dict[str, object] = {}
    for ax in axes.flat:
        handles, labels = ax.get_legend_handles_labels()
        for handle, label in zip(handles, labels, strict=True):
            seen.setdefault(label, handle)
    fig.legend(list(seen.values()), list(seen.keys()), loc="outside lower center", ncol=min(len(seen), 7),
               fontsize=8, frameon=False)


def position_error_figure(cases: list[dict], path: Path, title: str, with_spec: bool) -> None:
    """Position error over time of a study's cases (acroboter.studies.formulations.run_case): the whole run on the
    left, the first 1.5 s on the right; cases the method refused are left out."""
    import numpy as np

    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(12, 5), gridspec_kw={"width_ratios": [3, 2]})
    colors = plt.cm.tab10(np.linspace(0, 1, 10))
    shown = [c for c in cases if c["outcome"] != "refused"]
    # One colour per variant (spec, or recovery); penalty solid, iterative dashed.
    def key(c):
        return (c["spec"], c["method"] == "mlm") if with_spec else (c.get("recovery"), c.get("kappa"))

    keys = list(dict.fromkeys(key(c) for c in shown))
    for c in shown:
        label = (f"{c['spec']}: " if with_spec else "") + case_label(c)
        if c["diverged_at_s"] is not None:
            label += f" (diverged {c['diverged_at_s']:.2f} s)"
        err = np.maximum(np.asarray(c["position_error_mm"]), 1e-6)  # log axis: a zero error at t = 0
        style = {"color": colors[keys.index(key(c)) % 10], "lw": 1.0,
                 "ls": "--" if c["method"].startswith("iterative") else "-"}
        for ax in axes:
            ax.semilogy(c["t"], err, label=label, **style)
    for ax in axes:
        ax.axhline(5.3, color="k", ls=":", lw=1, label="paper's bound, 5.3 mm")
        ax.set_xlabel("t [s]")
        ax.grid(alpha=0.3, which="both")
    axes[1].set_xlim(0, 1.5)
    axes[0].set_ylabel("|r_SU − r_d| [mm]")
    axes[0].set_title("whole run")
    axes[1].set_title("first 1.5 s")
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=7, ncol=3, loc="lower center")
    fig.suptitle(title)
    fig.tight_layout(rect=(0, 0.07 + 0.02 * ((len(shown) + 3) // 3), 1, 1))  # room for the legend's rows
    fig.savefig(path, dpi=110)
    plt.close(fig)


def case_label(case: dict) -> str:
    """'method', or 'method / recovery κ=k' for the non-collocated crane's cases."""
    label = case["method"]
    if case.get("recovery"):
        label += f" / {case['recovery']}"
        if case.get("kappa") is not None:
            label += f" κ={case['kappa']:g}"
    return label


# ---------------------------------------------------------------------------------------------------
# The robustness Monte Carlo (acroboter.cli.robustness): rows of acroboter.studies.robustness_grid.COLUMNS_HEAD


def robustness_figures(out: Path, rows: list[dict], bins: int = 10, worst: dict | None = None) -> list[Path]:
    """CDF of the max position error per method (left ki = 0, right with ki), the success rate at the
    paper's bounds against the tracked body's relative mass error (binned), and, given `worst` (method ->
    {ki: Result}), the worst sample's position and yaw errors over time."""
    plt = _pyplot()
    methods = list(dict.fromkeys(r["method"] for r in rows if r["method"] is not None))  # None: a crashed task
    kis = sorted({r["ki"] for r in rows if r["ki"] is not None})
    colors = {m: plt.cm.tab10(i % 10) for i, m in enumerate(methods)}
    settled = any(r.get("max_position_error_settled_mm") is not None for r in rows)
    written = [_robustness_cdf(out, rows, methods, kis, colors, settled),
               _robustness_success(out, rows, methods, kis, colors, settled, bins)]
    if worst:
        written.append(_robustness_worst(out, worst, colors))
    return written


def _robustness_cdf(out: Path, rows: list[dict], methods: list, kis: list, colors: dict, settled: bool) -> Path:
    """The CDF of the max position error per method, a column per ki (and a row from the settled time on)."""
    import numpy as np
    from matplotlib.ticker import LogFormatterSciNotation, NullFormatter

    from ..studies.robustness_grid import POSITION_BOUND_MM, SETTLE_S

    plt = _pyplot()
    panels = [("max_position_error_mm", "max position error over the run [mm]")]
    if settled:
        panels.append(("max_position_error_settled_mm", f"max position error from t = {SETTLE_S:g} s on [mm]"))
    fig, axes = plt.subplots(len(panels), len(kis), figsize=(5.5 * len(kis), 3.6 * len(panels) + 0.4), sharey=True,
                             squeeze=False, layout="constrained")
    for pi, (key, xlabel) in enumerate(panels):
        for ax, ki in zip(axes[pi], kis, strict=True):
            for m in methods:
                sel = [r for r in rows if r["method"] == m and r["ki"] == ki]
                err = np.sort([r[key] if r["status"] == "ok" and r[key] is not None else np.inf for r in sel])
                ax.step(err, np.arange(1, len(err) + 1) / len(err), where="post", color=colors[m], label=m,
                        ls="--" if m.startswith("iterative") else "-")
            ax.axvline(POSITION_BOUND_MM, color="k", ls=":", lw=1, label=f"paper's bound {POSITION_BOUND_MM} mm")
            ax.set_xscale("log")
            ax.xaxis.set_major_formatter(LogFormatterSciNotation())
            ax.xaxis.set_minor_formatter(NullFormatter())
            ax.set_xlabel(xlabel)
            if pi == 0:
                ax.set_title(f"ki = {ki:g}" + (" (PD law)" if ki == 0 else " (integral action)"))
            ax.grid(alpha=0.3, which="both")
        axes[pi, 0].set_ylabel("fraction of samples ≤ error")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(f"Position error over {len({r['sample'] for r in rows})} plant samples (CDF; runs that did not "
                 "finish off the right edge)", fontsize=10)
    fig.savefig(out / "robustness_cdf.png", dpi=110)
    plt.close(fig)
    return out / "robustness_cdf.png"


def _robustness_success(out: Path, rows: list[dict], methods: list, kis: list, colors: dict, settled: bool,
                        bins: int) -> Path:
    """The success rate at the paper's bounds against the tracked body's relative mass error, binned."""
    import numpy as np

    from ..studies.robustness_grid import POSITION_BOUND_MM, SETTLE_S, YAW_BOUND_DEG

    plt = _pyplot()
    errs = np.array([r["tracked_mass_error"] for r in rows])
    edges = np.linspace(errs.min(), errs.max(), bins + 1) if len(rows) else np.array([0.0, 1.0])
    mids = 50 * (edges[:-1] + edges[1:])  # percent
    kinds = [("success", "over the whole run")] + ([("success_settled", f"from t = {SETTLE_S:g} s on")]
                                                   if settled else [])
    fig, axes = plt.subplots(1, len(kinds), figsize=(6.5 * len(kinds), 5.0), sharey=True, squeeze=False,
                             layout="constrained")
    for ax, (key, when) in zip(axes[0], kinds, strict=True):
        for m in methods:
            for ki in kis:
                rate = []
                for lo, hi in zip(edges[:-1], edges[1:], strict=True):
                    sel = [r for r in rows if r["method"] == m and r["ki"] == ki
                           and lo <= r["tracked_mass_error"] <= hi]
                    rate.append(100 * np.mean([bool(r[key]) for r in sel]) if sel else np.nan)
                ax.plot(mids, rate, marker="o", color=colors[m], ls="-" if ki == 0 else "--",
                        label=f"{m}, ki = {ki:g}")
        ax.set_xlabel("plant's SU mass against the model's [%] (bin centres)")
        ax.set_title(f"within {POSITION_BOUND_MM} mm and {YAW_BOUND_DEG}° {when}", fontsize=10)
        ax.set_ylim(-3, 103)
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("success rate [%]")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=5, fontsize=7, frameon=False)
    fig.suptitle("Success at the paper's bounds against the SU mass mismatch (the CC hangs on the main cable: "
                 "its mass barely matters)", fontsize=10)
    fig.savefig(out / "robustness_success.png", dpi=110)
    plt.close(fig)
    return out / "robustness_success.png"


def _robustness_worst(out: Path, worst: dict, colors: dict) -> Path:
    """The worst sample's position and yaw errors over time, re-run: every method, with and without ki."""
    import numpy as np

    from ..studies.robustness_grid import POSITION_BOUND_MM

    plt = _pyplot()
    fig, axes = plt.subplots(2, 1, figsize=(9, 6.5), sharex=True, layout="constrained")
    for m, by_ki in worst["results"].items():
        for ki, res in by_ki.items():
            style = {"color": colors.get(m, "k"), "ls": "-" if ki == 0 else "--", "lw": 1.0,
                     "label": f"{m}, ki = {ki:g}"}
            axes[0].semilogy(res.time, np.maximum(res.position_error_mm, 1e-6), **style)
            if res.yaw_error_deg is not None:
                axes[1].plot(res.time, np.abs(res.yaw_error_deg), **style)
    axes[0].axhline(POSITION_BOUND_MM, color="k", ls=":", lw=1)
    axes[0].set_ylabel("|r_SU − r_d| [mm]")
    axes[1].set_ylabel("|yaw error| [deg]")
    axes[1].set_xlabel("t [s]")
    for ax in axes:
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=7, ncol=2)
    fig.suptitle(f"Worst sample ({worst['sample']}: SU mass {100 * worst['tracked_mass_error']:+.1f} %, "
                 f"SU + CC {100 * worst['mass_error']:+.1f} %), re-run",
                 fontsize=10)
    fig.savefig(out / "robustness_worst.png", dpi=110)
    plt.close(fig)
    return out / "robustness_worst.png"
