"""Experiment drivers that precompute and simulate, and their markdown/JSON writers:
Table 2, speed/error and Pareto sweeps, tuning, scaling, large steps, the runs behind
the figures, the demo job. Only the command line and the scripts import them."""
