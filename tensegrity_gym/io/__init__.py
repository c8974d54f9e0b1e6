"""File input and output: the one atomic writer (:mod:`.atomic`) with its claims and
transactions (:mod:`.claim`), MJCF export (:mod:`.mjcf`),
tnsgrt import (:mod:`.tnsgrt`) and recorded trajectories (:mod:`.trajectory`)."""
