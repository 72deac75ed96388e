"""Skill-learning algorithms, each a config, an agent and presets; see algos.registry."""
