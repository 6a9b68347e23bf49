"""Figures of a run (``tensegrity-sim plot LOG``) and of a sweep (``tensegrity-sim plot TABLE.parquet``).

Each figure is written as PNG and SVG into one directory:

* ``tensions``: tension per cable over time (N), one row per cable, slack spans shaded grey and snaps
  (slack-to-taut changes) marked with a red triangle; scenes with more cables than
  :data:`MAX_CABLE_ROWS` show the cables that snap most (then the most tensioned), and say so;
* ``impulses``: the cable impulses of each publication interval (N*s), the same cables;
* ``energy``: kinetic, strain, gravity and total energy (J), recomputed by replaying the log;
* ``contacts``: one line per member pair, a bar while the pair is in contact.

A sweep's Parquet table (one row per run) gives ``sweep``: a result column against a parameter column,
one line per value of a third column if asked, failed runs left out and counted in the title.
"""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only: no display needed, none opened
matplotlib.rcParams["svg.fonttype"] = "none"  # SVG text stays text: searchable, editable, smaller
import matplotlib.pyplot as plt  # noqa: E402  (after the backend is chosen)
import numpy as np  # noqa: E402

from .record import RunRecord  # noqa: E402

__all__ = ["MAX_CABLE_ROWS", "plot_run", "plot_sweep", "FORMATS"]

MAX_CABLE_ROWS = 12        # rows of the tension and impulse figures; more cables: the most snapping ones
FORMATS = ("png", "svg")
_DPI = 110


def _save(fig, out: Path, name: str) -> list[Path]:
    paths = []
    for ext in FORMATS:
        path = out / f"{name}.{ext}"
        fig.savefig(path, dpi=_DPI)
        paths.append(path)
    plt.close(fig)
    return paths


def _spans(mask: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) indices of every run of True in ``mask`` (1-D bool)."""
    edges = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1))


def shown_cables(record: RunRecord) -> tuple[np.ndarray, str]:
    """Indices of the cables the tension and impulse figures show, and a note when not all are."""
    n = record.tensions.shape[1]
    if n <= MAX_CABLE_ROWS:
        return np.arange(n), ""
    snaps = np.bincount(record.snaps[1], minlength=n)
    # most snaps first, then the highest tension
    order = np.lexsort((-record.tensions.max(axis=0), -snaps))[:MAX_CABLE_ROWS]
    return np.sort(order), f"{MAX_CABLE_ROWS} of {n} cables: those that snap most"


def _cable_rows(record: RunRecord, title: str, ylabel: str):
    cables, note = shown_cables(record)
    fig, axes = plt.subplots(len(cables), 1, sharex=True, squeeze=False,
                             figsize=(9.0, 1.0 + 0.75 * len(cables)), layout="constrained")
    fig.suptitle(f"{title} - {record.title}" + (f"\n({note})" if note else ""))
    axes[-1, 0].set_xlabel("time (s)")
    fig.supylabel(ylabel)
    return fig, [ax for ax in axes[:, 0]], cables


def plot_tensions(record: RunRecord, out: Path) -> list[Path]:
    """``tensions.png/svg``: tension per cable, slack spans shaded, snaps marked."""
    fig, axes, cables = _cable_rows(record, "Cable tensions", "tension (N)")
    t = record.times
    snap_k, snap_c = record.snaps
    names = record.scene.cable_names
    for ax, c in zip(axes, cables):
        ax.plot(t, record.tensions[:, c], lw=0.9, color="tab:blue")
        for first, last in _spans(record.slack[:, c]):
            ax.axvspan(t[first], t[last], color="0.8", lw=0)
        mine = snap_k[snap_c == c]
        ax.plot(t[mine], record.tensions[mine, c], "^", color="tab:red", ms=4)
        ax.set_ylabel(names[c], rotation=0, ha="right", va="center")
        ax.margins(x=0)
    axes[0].legend(handles=[plt.Line2D([], [], color="tab:blue", lw=0.9, label="tension"),
                            plt.Rectangle((0, 0), 1, 1, color="0.8", label="slack"),
                            plt.Line2D([], [], ls="", marker="^", color="tab:red", label="snap")],
                   loc="upper right", ncols=3, fontsize="small", framealpha=0.9)
    return _save(fig, out, "tensions")


def plot_impulses(record: RunRecord, out: Path) -> list[Path]:
    """``impulses.png/svg``: each publication interval's summed impulse per cable."""
    fig, axes, cables = _cable_rows(record, "Cable impulses per publication interval", "impulse (N s)")
    names = record.scene.cable_names
    for ax, c in zip(axes, cables):
        ax.vlines(record.times, 0.0, record.impulses[:, c], lw=0.8, color="tab:purple")
        ax.set_ylabel(names[c], rotation=0, ha="right", va="center")
        ax.margins(x=0)
    return _save(fig, out, "impulses")


def plot_energy(record: RunRecord, out: Path) -> list[Path]:
    """``energy.png/svg``: the energy terms (``record.energy``) over time."""
    fig, ax = plt.subplots(figsize=(9.0, 4.0), layout="constrained")
    k = len(next(iter(record.energy.values()), ()))
    for name, values in record.energy.items():
        ax.plot(record.times[:k], values, lw=1.8 if name == "total" else 1.0, label=name,
                color="black" if name == "total" else None)
    ax.set(xlabel="time (s)", ylabel="energy (J)", title=f"Energy - {record.title}"
           + (f"\n{record.energy_note}" if record.energy_note else ""))
    ax.legend(loc="best", fontsize="small")
    ax.margins(x=0)
    return _save(fig, out, "energy")


def plot_contacts(record: RunRecord, out: Path) -> list[Path]:
    """``contacts.png/svg``: a time line per member pair, a bar while in contact."""
    start = {}
    bars: dict[tuple[str, str], list[tuple[float, float]]] = {}
    end_time = float(record.times[-1])
    for e in record.contacts:
        if e.kind == "begin":
            start[e.members] = e.time
            bars.setdefault(e.members, [])
        else:
            bars.setdefault(e.members, []).append((start.pop(e.members, 0.0), e.time))
    for members, t0 in start.items():  # still in contact when the log ends
        bars[members].append((t0, end_time))
    pairs = sorted(bars)
    fig, ax = plt.subplots(figsize=(9.0, 1.5 + 0.3 * len(pairs)), layout="constrained")
    for row, members in enumerate(pairs):
        # a contact shorter than a pixel still shows: at least 0.2 % of the time axis
        ax.broken_barh([(a, max(b - a, 0.002 * end_time)) for a, b in bars[members]], (row - 0.35, 0.7),
                       color="tab:orange")
    ax.set_yticks(range(len(pairs)), [f"{a} - {b}" for a, b in pairs])
    ax.set(xlim=(0.0, end_time), xlabel="time (s)", title=f"Contacts - {record.title}")
    if not pairs:
        ax.text(0.5, 0.5, "no contact", transform=ax.transAxes, ha="center", va="center", color="0.4")
        ax.set_yticks([])
    return _save(fig, out, "contacts")


def plot_run(record: RunRecord, out: str | Path) -> list[Path]:
    """Every figure of ``record`` into directory ``out`` (created): tensions and impulses if there are
    cables, energy if ``record.energy`` is set, contacts; the paths written."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = plot_tensions(record, out) + plot_impulses(record, out) if record.tensions.shape[1] else []
    if record.energy:
        paths += plot_energy(record, out)
    return paths + plot_contacts(record, out)


def plot_sweep(table, out: str | Path, *, x: str | None = None, y: str = "max_tension",
               by: str | None = None) -> list[Path]:
    """``sweep.png/svg`` in ``out``: column ``y`` against column ``x`` of a sweep's table (a
    ``pyarrow.Table``), one line per value of column ``by`` if given. ``x`` defaults to the first
    numeric column that is not ``y``. Runs whose ``failed`` column holds a reason are left out."""
    out = Path(out)
    columns = table.column_names
    numeric = [c for c in columns if _is_numeric(table, c)]
    x = x or next((c for c in numeric if c != y), None)
    for role, name in (("x", x), ("y", y), ("by", by)):
        if name is not None and name not in columns:
            raise ValueError(f"{role} column {name!r} is not in the table (columns: {', '.join(columns)})")
        if role != "by" and (name is None or name not in numeric):
            raise ValueError(f"{role} column {name!r} is not numeric (numeric columns: {', '.join(numeric)})")
    rows = table.to_pydict()
    ok = np.array([not f for f in rows["failed"]]) if "failed" in columns else np.ones(table.num_rows, bool)
    xs, ys = np.asarray(rows[x], dtype=float), np.asarray(rows[y], dtype=float)
    groups = [None] if by is None else sorted({v for v, good in zip(rows[by], ok) if good})
    out.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(7.0, 4.5), layout="constrained")
    for g in groups:
        keep = ok if g is None else ok & np.array([v == g for v in rows[by]])
        order = np.argsort(xs[keep], kind="stable")
        ax.plot(xs[keep][order], ys[keep][order], "o-", ms=4, label=None if g is None else f"{by} = {g}")
    failed = int(np.count_nonzero(~ok))
    ax.set(xlabel=x, ylabel=y, title=f"{y} against {x} ({int(ok.sum())} runs"
           + (f", {failed} failed and left out)" if failed else ")"))
    if by is not None:
        ax.legend(fontsize="small")
    ax.grid(alpha=0.3)
    return _save(fig, out, "sweep")


def _is_numeric(table, name: str) -> bool:
    import pyarrow.types as pat

    kind = table.schema.field(name).type
    return pat.is_integer(kind) or pat.is_floating(kind)
