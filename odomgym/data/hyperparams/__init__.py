"""Hyperparameters of the learned policies, one table per algorithm keyed by env id."""
