"""Segmentation and fusion evaluation: the paper's segmentation table, the loop's per-iteration figure, obstacles."""
