"""Perception per LiDAR model and stress scenario: `ssf eval sensors`."""
