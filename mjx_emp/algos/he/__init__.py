"""Hierarchical Empowerment (Levy et al.): goal-conditioned empowerment at every level of a k-level agent."""
