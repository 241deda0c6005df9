"""Simulation and run tooling outside the daemon: simulated poses (:mod:`.sim_pose`, :mod:`.routes`), run
analysis (:mod:`.analysis`) and the ``make demo`` job (:mod:`.demo`)."""
