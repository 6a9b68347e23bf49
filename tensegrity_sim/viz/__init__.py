"""Looking at a run: matplotlib figures (:mod:`.plots`) and a self-contained 3-D page (:mod:`.page`),
both made from a log read by :func:`tensegrity_sim.ros.record.read_log`."""
