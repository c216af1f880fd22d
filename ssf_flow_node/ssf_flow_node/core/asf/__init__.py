"""ASF-style scene flow network (set abstraction, point-to-patch cost volumes, coarse-to-fine flow)."""
