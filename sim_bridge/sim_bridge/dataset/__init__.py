"""Dataset export of simulator frame pairs with exact ground truth, and readers for exported and KITTI data."""
