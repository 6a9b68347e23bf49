"""The benchmarks' CSV files: written with 6 significant digits, read back with their numbers."""
from __future__ import annotations

import csv
from pathlib import Path

__all__ = ["write_csv", "read_csv"]


def write_csv(path: Path, rows: list[dict], fields: list[str] | None = None) -> None:
    """``rows`` under the header ``fields`` (default: the first row's keys); floats to 6 digits."""
    fields = fields or list(rows[0])
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=fields, extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})


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
