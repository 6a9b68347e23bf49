"""tensegrity_sim: tensegrity-structure dynamics with slack and snapping cables.

The numerical core (scene, system, methods, simulator) imports nothing from ROS, MCAP or file
formats beyond the scene loader.
"""
from ._kernel_cache import drop_stale as _drop_stale_kernels

_drop_stale_kernels()   # before any compiled kernel is loaded from numba's cache (see _kernel_cache)

from .accuracy import AccuracyChoice, choose_accuracy
from .batch import BatchSimulator
from .methods.contact.detection import ActiveContact
from .methods import METHODS, StepError
from .methods.inextensible.method import LengthOffsetWarning
from .methods.qp.solvers import SOLVERS, QPError
from .results import ContactEvent, StepResult, Trajectory
from .scene import Cable, ClassKWarning, Node, Scene, SceneError, Strut, builtin_scenes, load_scene
from .simulator import NonFiniteError, Simulator, SpeedError

__version__ = "0.1.0"

# robot files from other formats (tensegrity_sim.io): imported on first use, so that importing the package reads
# no file-format code (and MuJoCo's parser is imported only when an MJCF file is read)
_IO = ("load_mjcf", "load_ntrt")


def __getattr__(name: str):
    if name in _IO:
        from . import io
        return getattr(io, name)
    raise AttributeError(f"module 'tensegrity_sim' has no attribute {name!r}")


__all__ = [
    "METHODS", "Cable", "ClassKWarning", "ContactEvent", "Node", "Scene", "SceneError", "Simulator",
    "LengthOffsetWarning", "NonFiniteError", "QPError", "StepError", "SOLVERS", "StepResult", "Strut", "Trajectory",
    "SpeedError", "builtin_scenes",
    "load_scene", "__version__",
    "ActiveContact", "BatchSimulator", "AccuracyChoice", "choose_accuracy", "load_mjcf", "load_ntrt", "fit",
]


def fit(log, params: str, **options):
    """Fit scene parameters to a logged run by multiple shooting (``tensegrity-sim fit``; needs the jax extra):
    ``tensegrity_sim.ros.fit_log.fit_log``'s arguments (``scene``, ``window``, ``loss``, ``loss_scale``, ``out``,
    ``plot``). Returns the ``FitResult`` (start, fitted and sigma per parameter, the fitted scene, the estimated
    pose noise, the trajectories before and after)."""
    from .ros.fit_log import fit_log   # imported here: the core needs neither MCAP nor JAX

    return fit_log(log, params, **options)
