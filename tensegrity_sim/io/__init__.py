"""Robots in other formats: MuJoCo's MJCF (:mod:`.mjcf`, both ways) and NTRT's YAML (:mod:`.ntrt`, in).

This package sits around the core and imports it, never the reverse (style.md item 10). MuJoCo's parser is
an optional dependency (the ``io`` extra), imported only when an MJCF file is read; writing MJCF needs
nothing. A loader returns an :class:`Imported`: the scene, which cable each actuator drives, and the notes
that say how every element was mapped; what a format has and a scene cannot say is refused with a
:class:`~tensegrity_sim.scene.SceneError` naming the file and the element, or dropped with a
:class:`MappingWarning` saying what was dropped.
"""
from __future__ import annotations

from ._common import Imported, MappingWarning
from .mjcf import import_mjcf, load_mjcf, scene_to_mjcf
from .ntrt import import_ntrt, load_ntrt

__all__ = ["Imported", "MappingWarning", "import_mjcf", "import_ntrt", "load_mjcf", "load_ntrt", "scene_to_mjcf"]
