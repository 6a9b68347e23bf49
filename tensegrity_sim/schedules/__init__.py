"""Built-in command schedules (YAML, the format of :mod:`tensegrity_sim.commands`): ``prism3_demo``, the
main job's (``tensegrity-sim run`` without a scene); ``superball_roll`` and ``three_bar_roll``, which roll the
built-in robots (``tensegrity-sim run superball --commands tensegrity_sim/schedules/superball_roll.yaml``;
written by ``scripts/roll_schedules.py``)."""
