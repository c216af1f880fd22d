"""Closed-loop navigation benchmark: perception sources, the in-process loop, campaigns, statistics, plots."""
