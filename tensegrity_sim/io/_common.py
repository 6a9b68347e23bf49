"""What the loaders share: their result, their warning, names made valid."""
from __future__ import annotations

import re
from dataclasses import dataclass, field

from ..scene import Scene

__all__ = ["Imported", "MappingWarning", "scene_name"]


class MappingWarning(UserWarning):
    """Something of an imported model that a scene cannot say was dropped (the message says what)."""


@dataclass(frozen=True)
class Imported:
    """What a loader made of a robot file.

    ``scene``: the :class:`~tensegrity_sim.scene.Scene`; ``actuators``: actuator name -> the cable it drives
    (a scene has no actuators: drive that cable's rest length); ``notes``: one line per mapping decision
    (each geom's share of a rod's mass, each site's radial offset, the rest length each tendon got).
    """

    scene: Scene
    actuators: dict[str, str] = field(default_factory=dict)
    notes: tuple[str, ...] = ()

    def header(self) -> str:
        """The notes and the actuators as YAML comment lines (what ``tensegrity-sim import`` writes first)."""
        lines = [f"Imported from {self.scene.source} by tensegrity-sim import."]
        lines += [f"actuator {a} drives cable {c}" for a, c in self.actuators.items()]
        lines += list(self.notes)
        return "".join(f"# {line}\n" for line in lines)


_INVALID = re.compile(r"[^A-Za-z0-9_]")


def scene_name(raw: str, taken: set[str]) -> str:
    """``raw`` as a scene name (``[A-Za-z_][A-Za-z0-9_]*``: other characters become ``_``), made unique
    among ``taken`` by trailing underscores; the name is added to ``taken``."""
    name = _INVALID.sub("_", raw) or "_"
    if name[0].isdigit():
        name = "_" + name
    while name in taken:
        name += "_"
    taken.add(name)
    return name
