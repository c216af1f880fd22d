"""Live view without ROS: the graph's topics served over the Foxglove WebSocket protocol (foxglove-sdk), with the
ROS 2 schemas (`ros2msg`) and the CDR bytes exactly as they travel on the wire, as foxglove_bridge serves them on a
ROS 2 machine.

`server` holds the Foxglove side (channels, the WebSocket server), `node` the graph side (topic discovery, raw
subscriptions made when a client first subscribes), `command` the `ssf view` command and the `--foxglove` options
that `ssf demo`, `ssf launch` and `ssf bag play` share, `layout` the shipped Foxglove layout.
"""

LOOPBACK = "127.0.0.1"
DEFAULT_PORT = 8765
