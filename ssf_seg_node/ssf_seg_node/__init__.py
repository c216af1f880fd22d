"""ssf_seg_node: motion segmentation of the scene and the flow/segmentation fusion loop."""
