"""The velocity problem's QP backends (``solvers``: DAQP, OSQP, NNLS, the sparse dual method) and their
numba kernels (the working-set answer, DAQP's compiled call, the dual active-set method, SuperLU solves)."""
from .solvers import SOLVERS, QPError, Rows, make_solver

__all__ = ["SOLVERS", "QPError", "Rows", "make_solver"]
