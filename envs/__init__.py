"""Gymnasium environments of odomgym."""
