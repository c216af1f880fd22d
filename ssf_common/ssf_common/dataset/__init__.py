"""Labelled data every stage reads: scan pairs with ground truth (one record, one writer, one reader), KITTI
odometry sequences, mask models and synthetic scenes."""
