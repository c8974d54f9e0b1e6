"""File input and output: the one atomic writer (:mod:`.atomic`) with its claims and
transactions (:mod:`.claim`), MJCF export (:mod:`.mjcf`),
tnsgrt import (:mod:`.tnsgrt`), recorded trajectories (:mod:`.trajectory`) and a lab's recordings
of a real robot (:mod:`.recording`)."""
