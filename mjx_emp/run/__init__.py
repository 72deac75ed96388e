"""Runs: the run directory, the epoch loop, checkpoints, and evaluation of saved runs."""
