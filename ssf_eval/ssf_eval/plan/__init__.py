"""`ssf bench plan`: the MPC's solve time and fallbacks (no simulator needed)."""
