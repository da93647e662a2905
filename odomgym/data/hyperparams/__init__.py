"""Hyperparameters of the learned policies: ``<algo>.yml`` files in rl-baselines3-zoo's own
format (one key per env id), read by ``odomgym train`` and by ``python -m rl_zoo3.train``."""
