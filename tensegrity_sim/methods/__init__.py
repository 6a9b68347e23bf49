"""Stepping methods, picked by name from :data:`METHODS`; ``"auto"`` is :func:`choose_method`."""
from __future__ import annotations

from ..system import System
from .base import MethodStep, State, StepMethod
from .elastic import ElasticMethod

__all__ = ["METHODS", "choose_method", "make_method", "State", "MethodStep", "StepMethod"]

METHODS: dict[str, type[StepMethod]] = {
    ElasticMethod.name: ElasticMethod,
}


def choose_method(system: System, dt: float) -> tuple[str, str]:
    """The method ``"auto"`` resolves to for this scene and step, and the reason, in one sentence."""
    return "elastic", "elastic: the only method available"


def make_method(system: System, method: str, dt: float) -> tuple[StepMethod, str]:
    """Instantiate ``method`` (a name of :data:`METHODS` or ``"auto"``); returns it and the reason."""
    if method == "auto":
        method, reason = choose_method(system, dt)
    elif method in METHODS:
        reason = f"{method}: requested"
    else:
        raise ValueError(f"method must be one of {sorted(METHODS) + ['auto']}, got {method!r}")
    return METHODS[method](system, dt), reason
