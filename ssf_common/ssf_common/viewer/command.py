"""`ssf view`, and the `--foxglove [PORT]` options that `ssf demo`, `ssf launch` and `ssf bag play` share."""

from __future__ import annotations

import argparse
import sys
import threading
from typing import TYPE_CHECKING, Any

from ssf_common.viewer import DEFAULT_PORT, LOOPBACK

if TYPE_CHECKING:
    from ssf_common.viewer.server import ViewerConfig

VIEWER_NODE = "viewer"


def add_parser(top: argparse._SubParsersAction) -> None:
    """Register `ssf view`."""
    parser = top.add_parser(
        "view",
        help="serve the running graph's topics to the Foxglove app (live view, no ROS needed)",
        description="Join the running graph, discover its topics and serve them over the Foxglove WebSocket protocol "
        "(foxglove-sdk) with their ROS 2 schemas and CDR bytes as on the wire, until Ctrl-C. Open the printed "
        "ws:// address in the Foxglove app (Open connection > Foxglove WebSocket) and import "
        "docs/viewer/ssf.foxglove-layout.json. Listens on loopback unless --host says otherwise.",
    )
    parser.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"WebSocket port (default {DEFAULT_PORT}; 0: any)")
    parser.add_argument("--host", default=LOOPBACK,
                        help=f"interface to listen on (default {LOOPBACK}; 0.0.0.0 for every interface)")
    parser.set_defaults(func=run_view)


def add_foxglove_options(parser: argparse.ArgumentParser) -> None:
    """`--foxglove [PORT]` and `--foxglove-host HOST` on a command that runs or feeds a graph."""
    parser.add_argument("--foxglove", type=int, nargs="?", const=DEFAULT_PORT, default=None, metavar="PORT",
                        help=f"also serve the graph's topics to the Foxglove app on this port (default {DEFAULT_PORT})")
    parser.add_argument("--foxglove-host", default=LOOPBACK, metavar="HOST",
                        help=f"interface the --foxglove server listens on (default {LOOPBACK})")


def viewer_config(args: argparse.Namespace, source: str) -> ViewerConfig | None:
    """The viewer a command's --foxglove options ask for (None without --foxglove); ConfigError for a bad one."""
    from ssf_common.config import build
    from ssf_common.viewer.server import ViewerConfig

    if getattr(args, "foxglove", None) is None:
        return None
    return build(ViewerConfig, {"port": args.foxglove, "host": args.foxglove_host}, source=f"{source} --foxglove")


def run_view(args: argparse.Namespace) -> int:
    """Serve the graph until SIGINT/SIGTERM."""
    from ssf_common.config import build
    from ssf_common.middleware import run
    from ssf_common.viewer.node import make_viewer_class
    from ssf_common.viewer.server import FoxgloveServer, ViewerConfig

    config = build(ViewerConfig, {"port": args.port, "host": args.host}, source="ssf view")
    server = FoxgloveServer(config)
    announce(server)
    viewer = make_viewer_class()
    try:
        return run(lambda argv: viewer(server, argv=argv), argv=[])
    finally:
        server.stop()


def announce(server: Any) -> None:
    """Say on stderr where the Foxglove app connects."""
    print(f"view: Foxglove WebSocket server on {server.url} (Foxglove app: Open connection > Foxglove WebSocket)",
          file=sys.stderr, flush=True)


class BackgroundViewer:
    """The viewer node spinning on a thread of this process (beside `ssf bag play`)."""

    def __init__(self, config: ViewerConfig) -> None:
        from ssf_common.viewer.node import make_viewer_class
        from ssf_common.viewer.server import FoxgloveServer

        self.server = FoxgloveServer(config)
        announce(self.server)
        self.node = make_viewer_class()(self.server)
        self._thread: threading.Thread = self.node.spin_in_thread()

    def close(self) -> None:
        """Stop the node and the server."""
        self.node.request_shutdown()
        self._thread.join(timeout=5.0)
        self.node.destroy_node()
        self.server.stop()
