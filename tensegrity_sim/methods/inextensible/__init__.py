"""Method 1 (physics.md §3): inextensible cables — the method class (``method``), the published impulses'
self-stress rule (``self_stress``) and their numba kernels (``_kernels``, ``_self_stress_kernels``)."""
from .method import InextensibleMethod, LengthOffsetWarning

__all__ = ["InextensibleMethod", "LengthOffsetWarning"]
