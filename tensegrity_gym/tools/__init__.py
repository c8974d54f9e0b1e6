"""User tools on top of the physics and the envs: the command line (:mod:`.cli`), system
identification (:mod:`.sysid`), rendering and trajectory viewers (:mod:`.rendering`) and scripted
baseline controllers (:mod:`.baselines`)."""
