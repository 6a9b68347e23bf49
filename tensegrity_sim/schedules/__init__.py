"""Built-in command schedules (YAML, the format of :mod:`tensegrity_sim.commands`): ``prism3_demo``, the
main job's (``tensegrity-sim run`` without a scene)."""
