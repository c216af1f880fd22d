"""SSF-PAN common library: middleware, messages, point clouds, bags, config, geometry (the application is ssf_bringup)."""
