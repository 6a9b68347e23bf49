"""The benchmarks' CSV files: written with 6 significant digits and a provenance sidecar, read back with their
numbers, and shown as Markdown tables (the documentation site and README quote them, never retype them).

Every ``write_csv(path, ...)`` also writes ``path.json`` beside the CSV (``bench/results/x.csv`` ->
``bench/results/x.csv.json``): the command line that ran, the machine lines (CPU, cores, load, OS, versions,
commit: ``bench/report.py``'s ``machine()``), the commit alone and the date. ``markdown_table`` renders a CSV with
that provenance under it; ``docs/hooks.py`` calls it for ``{{ table("x.csv") }}`` on a page.
"""
from __future__ import annotations

import csv
import datetime
import json
import math
import shlex
import subprocess
import sys
from pathlib import Path

__all__ = ["write_csv", "read_csv", "provenance", "markdown_table", "source_line", "cell", "select", "ROOT", "RESULTS"]

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results"


def _command() -> str:
    """This process's command line as one would type it at the repository root (``python3 bench/x.py ...``)."""
    script = Path(sys.argv[0]) if sys.argv and sys.argv[0] else Path("python")
    try:
        script = script.resolve().relative_to(ROOT)
    except ValueError:
        pass
    return shlex.join(["python3", str(script), *sys.argv[1:]])


def write_csv(path: Path, rows: list[dict], fields: list[str] | None = None) -> None:
    """``rows`` under the header ``fields`` (default: the first row's keys); floats to 6 digits. Writes the
    provenance sidecar ``path.json`` too (command line, machine lines, commit, date: see the module's docstring)."""
    from bench.report import machine

    path = Path(path)
    fields = fields or list(rows[0])
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=fields, extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})
    lines = machine()
    # the commit as machine() gives it: short hash, marked when files outside bench/results differ from it
    commit = next(line for line in lines if " at commit " in line).split(" at commit ", 1)[1].split(";", 1)[0]
    meta = {"command": _command(), "machine": lines, "commit": commit,
            "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")}
    Path(f"{path}.json").write_text(json.dumps(meta, indent=1) + "\n")


def _value(text: str):
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def read_csv(path: Path) -> list[dict]:
    """The rows of ``path``, numbers as int or float (empty cells as NaN), text as str."""
    with open(path, newline="") as fh:
        return [{k: (float("nan") if v == "" else _value(v)) for k, v in row.items()} for row in csv.DictReader(fh)]


def provenance(path: Path) -> dict:
    """What ran to write the CSV ``path``: its sidecar ``path.json`` (``command``, ``machine`` lines,
    ``commit``, ``date``). A CSV written before sidecars existed has none: then only the commit that last
    changed the file is known (from git), and ``command`` and ``machine`` are None."""
    path = Path(path)
    sidecar = Path(f"{path}.json")
    if sidecar.exists():
        return json.loads(sidecar.read_text())
    try:
        log = subprocess.run(["git", "log", "-1", "--format=%h %ad", "--date=short", "--", str(path)], cwd=ROOT,
                             capture_output=True, text=True, check=True).stdout.split()
    except (OSError, subprocess.CalledProcessError):
        log = []
    return {"command": None, "machine": None, "commit": log[0] if log else "uncommitted",
            "date": log[1] if len(log) > 1 else None}


def cell(value, digits: int = 3) -> str:
    """A table cell: integers with thousands separators, floats to ``digits`` significant digits, NaN as '-'."""
    if isinstance(value, bool) or value is None:
        return "-" if value is None else str(value)
    if isinstance(value, int):
        return f"{value:,}"
    if isinstance(value, float):
        if not math.isfinite(value):
            return "-"
        if value == int(value) and abs(value) < 1e15:
            return f"{int(value):,}"
        if 1e-3 <= abs(value) < 1e6:
            return f"{round(value):,}" if abs(value) >= 10 ** digits else f"{value:.{digits}g}"
        return f"{value:.{digits - 1}e}"
    return str(value).replace("|", "\\|")


def select(rows: list[dict], where: dict | None) -> list[dict]:
    """The rows that hold, in every column of ``where``, its value (or one of its list of values)."""
    where = {k: (v if isinstance(v, (list, tuple)) else [v]) for k, v in (where or {}).items()}
    return [row for row in rows if all(row.get(column) in options for column, options in where.items())]


def markdown_table(path: Path, columns: list[str] | dict | None = None, where: dict | None = None,
                   digits: int = 3, source: bool = True) -> str:
    """The CSV ``path`` as a Markdown table, with its provenance under it.

    ``columns``: the columns to show, in order (default: all), or a mapping {column: header}; ``where``:
    keep only the rows whose column holds the value (or one of a list of values); ``digits``: significant
    digits of floats; ``source``: add the line naming the file, command, commit, date and machine.
    A column or filter that names no column of the file raises ``ValueError`` (a page must not silently
    show an empty table)."""
    path = Path(path)
    rows = read_csv(path)
    if not rows:
        raise ValueError(f"{path}: no rows")
    headers = dict(columns) if isinstance(columns, dict) else {c: c for c in (columns or rows[0])}
    unknown = [c for c in [*headers, *(where or {})] if c not in rows[0]]
    if unknown:
        raise ValueError(f"{path}: no column {', '.join(map(repr, unknown))}; it has {', '.join(rows[0])}")
    rows = select(rows, where)
    if not rows:
        raise ValueError(f"{path}: no row matches {where}")
    lines = ["| " + " | ".join(headers.values()) + " |", "|" + " --- |" * len(headers)]
    lines += ["| " + " | ".join(cell(row[c], digits) for c in headers) + " |" for row in rows]
    text = "\n".join(lines) + "\n"
    return text + ("\n" + source_line(path) + "\n" if source else "")


def source_line(path: Path) -> str:
    """One Markdown line: which file, written by which command, at which commit, on which machine."""
    path = Path(path)
    meta = provenance(path)
    try:
        name = path.resolve().relative_to(ROOT)
    except ValueError:
        name = path
    text = f"*Source: `{name}`"
    text += f", written by `{meta['command']}`" if meta.get("command") else " (command not recorded)"
    text += f" at commit {meta['commit']}" + (f" on {meta['date']}" if meta.get("date") else "")
    if meta.get("machine"):
        text += "; machine: " + " ".join(line.lstrip("- ").rstrip(".") + "." for line in meta["machine"])
    else:
        text += "; machine not recorded"
    return text + (f" ({meta['note']})" if meta.get("note") else "") + "*"
