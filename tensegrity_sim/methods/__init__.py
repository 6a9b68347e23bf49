"""Stepping methods, picked by name from :data:`METHODS`; ``"auto"`` is :func:`choose_method`."""
from __future__ import annotations

from ..system import System
from .base import MethodStep, State, StepMethod
from .elastic import ElasticMethod
from .inextensible import InextensibleMethod
from .qp import SOLVERS

__all__ = ["METHODS", "SOLVERS", "choose_method", "make_method", "State", "MethodStep", "StepMethod"]

METHODS: dict[str, type[StepMethod]] = {
    ElasticMethod.name: ElasticMethod,
    InextensibleMethod.name: InextensibleMethod,
}


def choose_method(system: System, dt: float) -> tuple[str, str]:
    """The method ``"auto"`` resolves to for this scene and step, and the reason, in one sentence."""
    return "elastic", "elastic: the only method available"


def make_method(system: System, method: str, dt: float, *, solver: str | None = None) -> tuple[StepMethod, str]:
    """Instantiate ``method`` (a name of :data:`METHODS` or ``"auto"``); returns it and the reason.

    ``solver`` names a QP backend (:data:`SOLVERS`) for a method that solves QPs."""
    if solver is not None and solver not in SOLVERS:
        raise ValueError(f"solver must be one of {sorted(SOLVERS)}, got {solver!r}")
    if method == "auto":
        method, reason = choose_method(system, dt)
    elif method in METHODS:
        reason = f"{method}: requested"
    else:
        raise ValueError(f"method must be one of {sorted(METHODS) + ['auto']}, got {method!r}")
    cls = METHODS[method]
    options = {}
    if solver is not None:
        if "solver" in cls.options:
            options["solver"] = solver
        elif reason.endswith("requested"):
            raise ValueError(f"solver={solver!r} is an option of a method with a QP; method {method!r} has none")
    return cls(system, dt, **options), reason
