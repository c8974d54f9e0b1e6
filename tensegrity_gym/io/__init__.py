"""File input and output: the one atomic writer (:mod:`.atomic`), MJCF export (:mod:`.mjcf`),
tnsgrt import (:mod:`.tnsgrt`) and recorded trajectories (:mod:`.trajectory`)."""
