"""Method 2 (physics.md §4): massless elastic cables — the method class (``method``), its located and
order-4 options (``composition``), the batch driver (``batch``) and their numba kernels (``_kernels``,
``_composition_kernels``), each kernel beside the numpy reference it must match."""
from .method import ElasticMethod

__all__ = ["ElasticMethod"]
