"""SSF-PAN common layer: middleware, messages, point clouds, bags, config and the `ssf` command line."""
