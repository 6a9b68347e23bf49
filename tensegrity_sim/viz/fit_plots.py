"""The figures of a fit (``tensegrity-sim fit --plot``): the logged and the simulated trajectories node by node,
before (the start values) and after the fit, and the residual over time."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .plots import _save, plt

__all__ = ["plot_fit"]


def plot_fit(result, out: Path) -> list[Path]:
    """``fit_positions.png/svg`` (one panel per node: x, y, z logged as dots, simulated before as thin lines,
    after as thick ones; the windows' restarts show as steps) and ``fit_residual.png/svg`` (each pose's rms
    distance to the simulated one, before and after) of a ``FitResult``, in ``out``. Returns the paths."""
    out.mkdir(parents=True, exist_ok=True)
    t = result.grid_steps * result.dt
    n = result.observed.shape[1]
    cols = min(n, 4)
    rows = -(-n // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.2 * rows), sharex=True, squeeze=False)
    names = result.scene.node_names
    for i, ax in enumerate(axes.flat):
        if i >= n:
            ax.set_visible(False)
            continue
        for j, colour in enumerate(("tab:red", "tab:green", "tab:blue")):
            ax.plot(t, result.observed[:, i, j], ".", ms=2, color=colour)
            ax.plot(t, result.before[:, i, j], "-", lw=0.6, color=colour, alpha=0.4)
            ax.plot(t, result.after[:, i, j], "-", lw=1.2, color=colour)
        ax.set_title(names[i], fontsize=8)
        ax.tick_params(labelsize=7)
    fig.suptitle("logged (dots) and simulated positions x, y, z (m): before (thin), after the fit (thick)",
                 fontsize=9)
    fig.supxlabel("time (s)", fontsize=8)
    fig.tight_layout()
    paths = _save(fig, out, "fit_positions")
    fig, ax = plt.subplots(figsize=(7, 3))
    for label, sim in (("before", result.before), ("after", result.after)):
        err = np.sqrt(np.nanmean(np.sum((sim - result.observed) ** 2, axis=2), axis=1))
        ax.semilogy(t, err, label=label)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("rms distance to the log (m)")
    ax.legend()
    fig.tight_layout()
    return paths + _save(fig, out, "fit_residual")
