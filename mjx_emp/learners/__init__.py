"""Learners: losses and one update step each, shared by every algorithm that uses them."""
