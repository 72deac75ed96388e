"""Environments: the domain registry (plain Python), MJX environments, scripted controllers."""
