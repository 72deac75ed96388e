"""Rollouts on device: the one-scan k-level hierarchy and the collect-until-done loop."""
