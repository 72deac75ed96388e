"""Plots and renders of runs, drawn from what agents record."""
