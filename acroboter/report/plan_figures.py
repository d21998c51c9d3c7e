"""A retiming's figure (`acroboter plan`'s plan.png): the path parameter s(t) and its rate, and each bounded
input along the path against its limits and the limits less the margin."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def plan_figure(plan, path: str | Path) -> Path:
    from matplotlib.figure import Figure

    lower, upper = plan.limits
    low, high = plan.bounds
    bounded = [i for i in range(len(plan.input_names)) if np.isfinite(lower[i]) or np.isfinite(upper[i])]
    fig = Figure(figsize=(9, 2.4 * (1 + len(bounded)) + 0.4))
    axes = fig.subplots(1 + len(bounded), 1, sharex=False, squeeze=False)[:, 0]
    ax = axes[0]
    ax.plot(plan.times, plan.s, label="s (path parameter, 0..1)")
    ax.plot(plan.times, plan.sd * (plan.times[-1] or 1.0), label="ṡ · duration")
    ax.set_xlabel("t [s]")
    ax.set_title(f"planned {plan.duration:.4g} s (the path's own timing {plan.path_duration:.4g} s, best uniform "
                 f"slowdown {plan.uniform_duration:.4g} s)")
    ax.legend(loc="best", fontsize=8)
    ax.grid(alpha=0.3)
    s_inputs = np.interp(plan.input_times, plan.times, plan.s)
    for ax, i in zip(axes[1:], bounded, strict=True):
        name, unit = plan.input_names[i], plan.input_units[i]
        ax.plot(s_inputs, plan.inputs[:, i], label=f"{name}, planned (ideal)")
        if plan.certificate is not None:  # on the path (the certificate flies on past its end, the point held)
            on = plan.certificate.times <= plan.input_times[-1] + 1e-9
            flown_s = np.interp(plan.certificate.times[on], plan.input_times, s_inputs)
            ax.plot(flown_s, plan.certificate.inputs[on, i], lw=0.8, alpha=0.8, label=f"{name}, flown (MLM)")
        for value, style, label in ((upper[i], "-", "limit"), (lower[i], "-", None), (high[i], "--", "less the margin"),
                                    (low[i], "--", None)):
            if np.isfinite(value):
                ax.axhline(value, color="k", ls=style, lw=0.8, label=label)
        ax.set_ylabel(f"{name} [{unit}]")
        ax.set_xlabel("s (along the path)")
        ax.legend(loc="best", fontsize=8)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return Path(path)
