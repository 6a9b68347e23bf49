"""Argument checks shared by every public boundary: the simulators, the scene and command loaders, the
node's parameters and messages, the command line.

Each check takes a value of any Python type and either returns it converted or raises ``ValueError``
whose message starts with the argument's name and shows the value (shortened, see :func:`describe`);
nothing else escapes, so a caller's ``except ValueError`` is the whole net. They run once, where a value
comes in, never inside a step loop.
"""
from __future__ import annotations

import functools
import math
import numbers
import os
import reprlib
import stat
from pathlib import Path
from typing import Any, Callable

import numpy as np
import yaml

__all__ = ["MIN_DT", "MAX_YAML_DEPTH", "describe", "real", "time_step", "whole", "float_array", "check_memory",
           "read_yaml"]

# Every stamp and log time is an integer number of nanoseconds, so a step shorter than one cannot be
# told from the next; below it, 1/dt and impulse/dt also leave the float range for ordinary impulses.
MIN_DT = 1e-9  # s

_repr = reprlib.Repr()
_repr.maxstring = _repr.maxother = 60
_repr.maxlist = _repr.maxtuple = _repr.maxdict = _repr.maxset = 6
_repr.maxlevel = 3


def describe(value: Any) -> str:
    """A short repr of ``value`` for an error message: bounded in length and depth (a nested or
    self-referencing structure, a huge integer, a long string all print in one short line)."""
    if type(value) is int and value.bit_length() <= 64:   # reprlib's text without its cost (each run() names
        return str(value)                                   # its kept steps)
    if isinstance(value, int) and not isinstance(value, bool) and value.bit_length() > 64:
        return f"an integer of {len(str(abs(value))) if value.bit_length() < 10_000 else 'over 3000'} digits"
    try:
        text = _repr.repr(value)
    except Exception:  # a user's object whose __repr__ fails still gets a message
        return f"a {type(value).__name__}"
    return " ".join(text.split())  # one line (numpy arrays print on several)


def real(value: Any, name: str) -> float:
    """``value`` as a finite float; bools, strings, containers and integers beyond the float range are
    refused (``ValueError`` naming ``name``)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name} must be a number, got {describe(value)}")
    try:
        out = float(value)
    except OverflowError:
        raise ValueError(f"{name} is too large for a float: {describe(value)}") from None
    if not math.isfinite(out):
        raise ValueError(f"{name} must be finite, got {describe(value)}")
    return out


def time_step(dt: Any, name: str = "dt") -> float:
    """A step ``dt`` in seconds: a finite number of at least :data:`MIN_DT`."""
    dt = real(dt, name)
    if dt < MIN_DT:
        raise ValueError(f"{name} must be a number of seconds >= {MIN_DT:g} (stamps are integer nanoseconds), "
                         f"got {dt!r}")
    return dt


def whole(value: Any, name: str) -> int:
    """A whole number >= 0 (an int, or a float with an integral value)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name} must be a whole number >= 0, got {describe(value)}")
    if isinstance(value, numbers.Integral):
        out = int(value)
    else:
        f = float(value)
        if not math.isfinite(f) or f != math.floor(f):
            raise ValueError(f"{name} must be a whole number >= 0, got {describe(value)}")
        out = int(f)
    if out < 0:
        raise ValueError(f"{name} must be a whole number >= 0, got {describe(value)}")
    return out


def float_array(values: Any, name: str, shape: tuple[int, ...] | None = None) -> np.ndarray:
    """``values`` (a number, a sequence, an array) as a new float64 array of ``shape`` (if given), every
    entry finite. Strings, complex numbers, ragged or nested-object input are refused."""
    if isinstance(values, (str, bytes)) or (isinstance(values, np.ndarray) and values.dtype.kind not in "biuf"):
        raise ValueError(f"{name} must be numbers, got {describe(values)}")
    try:
        arr = np.array(values, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name} must be numbers, got {describe(values)}") from None
    if shape is not None and arr.shape != shape:
        expected = "a number" if shape == () else f"an array of shape {shape}"
        raise ValueError(f"{name} must be {expected}, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite, got {describe(values)}")
    return arr


@functools.cache
def _physical_memory() -> int | None:
    """This machine's physical memory, bytes (None: not a POSIX system, no bound known); asked once (the
    system call took ~50 us of every run, an environment's control period among them)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):
        return None


def check_memory(nbytes: int, what: str) -> None:
    """Refuse to allocate ``nbytes`` for ``what`` when it exceeds this machine's physical memory (an
    absurd request would otherwise fail in numpy, or swap the machine to a standstill)."""
    physical = _physical_memory()
    if physical is None:
        return
    if nbytes > physical:
        shown = f"{nbytes:.3g}" if nbytes < 1e300 else "over 1e300"
        raise ValueError(f"{what} would need {shown} bytes, more than this machine's memory ({physical:.3g} bytes)")


# A scene or schedule file larger than this is refused unread (a 100-stage tower's scene is ~0.5 MiB)
MAX_YAML_BYTES = 64 << 20

# YAML nesting deeper than this is refused while composing (a scene or a schedule nests 4 deep): PyYAML
# would otherwise recurse until Python's limit, spending seconds on a few kilobytes of brackets.
MAX_YAML_DEPTH = 64


class _BoundedLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing nesting deeper than :data:`MAX_YAML_DEPTH`."""

    _depth = 0

    def compose_node(self, parent, index):
        self._depth += 1
        try:
            if self._depth > MAX_YAML_DEPTH:
                raise yaml.composer.ComposerError(None, None, f"nested deeper than {MAX_YAML_DEPTH} levels",
                                                  self.peek_event().start_mark)
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def read_yaml(path: str | Path, error: Callable[[str], Exception], text: str | None = None) -> Any:
    """The content of a YAML file (or of ``text``, named ``path``), as PyYAML's safe loader gives it.

    Every way it can fail (unreadable, not UTF-8, not YAML, nested deeper than :data:`MAX_YAML_DEPTH`, a
    value PyYAML cannot build) is raised as ``error(message)``, the message starting with ``path``."""
    if text is None:
        try:
            with open(path, "rb") as f:
                if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):
                    raise error(f"{path}: not a regular file (a device or a pipe may never end)")
                raw = f.read(MAX_YAML_BYTES + 1)
        except OSError as exc:
            raise error(f"{path}: cannot read: {exc.strerror}") from None
        if len(raw) > MAX_YAML_BYTES:
            raise error(f"{path}: larger than {MAX_YAML_BYTES >> 20} MiB: not a scene or a schedule")
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise error(f"{path}: not UTF-8 text (byte {exc.start}: {raw[exc.start:exc.start + 1]!r})") from None
    try:
        return yaml.load(text, Loader=_BoundedLoader)  # noqa: S506 (a SafeLoader)
    except yaml.YAMLError as exc:
        raise error(f"{path}: not valid YAML: {' '.join(str(exc).split())}") from None
    except Exception as exc:  # noqa: BLE001 - PyYAML's constructors raise what a value's conversion raises:
        # ValueError for a date out of range, OverflowError for a long sexagesimal number, AttributeError
        # for a malformed !!timestamp
        raise error(f"{path}: a value cannot be read ({type(exc).__name__}: {' '.join(str(exc).split())})") from None
