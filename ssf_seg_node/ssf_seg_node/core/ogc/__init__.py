"""The OGC-style segmentation network, its self-supervised losses, training and checkpoints (torch, no ROS)."""
