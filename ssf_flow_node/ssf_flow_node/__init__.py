"""ssf_flow_node: scene flow estimation between consecutive LiDAR scans."""
