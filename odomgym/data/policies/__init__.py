"""Trained policies shipped with odomgym (see each file's metadata for the command that made it)."""
