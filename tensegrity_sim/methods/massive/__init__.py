"""The full model of physics.md §4b (seed eq. 9): elastic cables with mass, a snap a plastic impact on the
cable's plate — the method class (``method``); methods 1 and 2 are its limits."""
from .method import MassiveMethod

__all__ = ["MassiveMethod"]
