"""The running daemon: wiring, threads and states (:mod:`.daemon`), the control tick (:mod:`.control`), the
receding-horizon planner (:mod:`.planner`) and its process (:mod:`.worker`), config → components
(:mod:`.wiring`), sd_notify (:mod:`.systemd`) and MCAP recording (:mod:`.recorder`)."""
