"""Geometry shared by every stage, written once: pure numpy/scipy (plus Open3D's and scikit-learn's C++ where
they are faster; torch only in `torch_ops`), no ROS.

| module | what |
| --- | --- |
| `se3` | 4x4 rigid transforms: make, compose, invert, relative pose, yaw, apply to points, rigid flow |
| `fitting` | weighted Kabsch (single and batched per label), planar Kabsch, per-label point-to-plane Gauss-Newton |
| `labels` | per-label sums, means, counts and extents (bincount-based) |
| `sampling` | one `Sampling` enum: random / voxel / farthest-point, and the index samplers |
| `neighbours` | KD-tree kNN and radius queries, inverse-distance propagation, Chamfer distance |
| `clustering` | connected components of voxels or within the measured point spacing, neighbours in the sensor's view; DBSCAN / HDBSCAN from scikit-learn |
| `ground` | height above the local ground on a grid (or per range and azimuth zone), ground mask |
| `boxes` | minimum-area oriented rectangles of point sets |
| `torch_ops` | the same for torch tensors inside networks: FPS, kNN and ball grouping (KD-tree on CPU, chunked elsewhere), gather, interpolation |
"""
