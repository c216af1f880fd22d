"""`ssf bench view`: what the live view costs. Clouds go from this process to a plain subscriber process (the
baseline, `ssf bench transport`'s) and, in the same run, through an `ssf view` process to a Foxglove WebSocket
client here; latency is measured from the header stamp (wall clock at publishing) to arrival."""

from __future__ import annotations

import argparse
import json
import re
import struct
import subprocess
import sys
import threading
import time
from dataclasses import asdict, dataclass
from typing import Any

SUBPROTOCOL = "foxglove.sdk.v1"
MESSAGE_DATA = 0x01


@dataclass(frozen=True)
class ViewBench:
    """What `ssf bench view` reports (milliseconds unless named otherwise)."""

    points: int
    rate_hz: float
    duration_s: float
    sent: int
    viewer_latency_p50_ms: float
    viewer_latency_p99_ms: float
    viewer_received_ratio: float
    subscriber_latency_p50_ms: float  # the baseline: a plain subscriber process, same clouds, same run
    subscriber_latency_p99_ms: float
    subscriber_received_ratio: float
    viewer_cpu_percent: float  # of one core, while serving
    viewer_peak_rss_mb: float


class _Client:
    """A Foxglove WebSocket client on a thread: subscribes to one topic once advertised, records latencies."""

    def __init__(self, url: str, topic: str) -> None:
        self.url, self.topic = url, topic
        self.latencies_ms: list[float] = []
        self.subscribed = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        from websockets.sync.client import connect

        from ssf_common.render.frames import header_stamp

        with connect(self.url, subprotocols=[SUBPROTOCOL], open_timeout=20, max_size=None) as ws:
            while not self._stop.is_set():
                try:
                    frame = ws.recv(timeout=0.2)
                except TimeoutError:
                    continue
                arrived = time.time_ns()
                if isinstance(frame, str):
                    message = json.loads(frame)
                    for channel in message.get("channels", []) if message["op"] == "advertise" else []:
                        if channel["topic"] == self.topic:
                            subscribe = json.dumps({"op": "subscribe",
                                                    "subscriptions": [{"id": 1, "channelId": channel["id"]}]})
                            ws.send(subscribe)
                            self.subscribed.set()
                    if message["op"] == "status" and "unknown channel" in message.get("message", "").lower():
                        time.sleep(0.2)  # a channel advertised while the client connected: the SDK was not ready
                        ws.send(subscribe)
                elif frame[0] == MESSAGE_DATA and struct.unpack_from("<I", frame, 1)[0] == 1:
                    self.latencies_ms.append((arrived - header_stamp(frame[13:])) / 1e6)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)


def run_bench_view(points: int, rate_hz: float, duration_s: float, say: Any) -> ViewBench:
    """Serve the bench topic with `ssf view`, publish, and measure both paths."""
    import psutil

    from ssf_common.bench_transport import BENCH_TOPIC, measure_latency, percentile
    from ssf_common.middleware import QOS_SENSOR_DATA, Node

    viewer = subprocess.Popen([sys.executable, "-P", "-m", "ssf_bringup.cli", "view", "--port", "0"],
                              stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
    try:
        url = _announced_url(viewer)
        warm = Node("ssf_bench_view_warmup")  # the topic exists before the run: the client is watching from the start
        warm.create_publisher("sensor_msgs/msg/PointCloud2", BENCH_TOPIC, QOS_SENSOR_DATA)
        client = _Client(url, BENCH_TOPIC)
        if not client.subscribed.wait(30.0):
            raise RuntimeError("the viewer never advertised the bench topic")
        time.sleep(1.5)  # the viewer's reader matches the writers
        process = psutil.Process(viewer.pid)
        cpu_before, started = process.cpu_times(), time.monotonic()
        say(f"{points} points at {rate_hz:g} Hz for {duration_s:g} s, to a subscriber process and through ssf view")
        baseline, sent = measure_latency(points, rate_hz, duration_s)
        cpu_after, elapsed = process.cpu_times(), time.monotonic() - started
        rss_mb = process.memory_info().rss / 2**20
        time.sleep(0.5)
        client.close()
        warm.destroy_node()
    finally:
        viewer.terminate()
        viewer.wait(timeout=20)
    busy = (cpu_after.user + cpu_after.system) - (cpu_before.user + cpu_before.system)
    viewed = client.latencies_ms
    return ViewBench(
        points=points, rate_hz=rate_hz, duration_s=duration_s, sent=sent,
        viewer_latency_p50_ms=round(percentile(viewed, 50), 3), viewer_latency_p99_ms=round(percentile(viewed, 99), 3),
        viewer_received_ratio=round(len(viewed) / sent, 4),
        subscriber_latency_p50_ms=round(percentile(baseline, 50), 3),
        subscriber_latency_p99_ms=round(percentile(baseline, 99), 3),
        subscriber_received_ratio=round(len(baseline) / sent, 4),
        viewer_cpu_percent=round(100.0 * busy / elapsed, 1), viewer_peak_rss_mb=round(rss_mb, 1),
    )


def _announced_url(viewer: subprocess.Popen, timeout_s: float = 60.0) -> str:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        line = viewer.stderr.readline()
        if match := re.search(r"on (ws://\S+:\d+)", line):
            return match.group(1)
        if not line and viewer.poll() is not None:
            break
    raise RuntimeError("ssf view announced no address")


def add_parser(bench: argparse._SubParsersAction) -> None:
    """Register `ssf bench view`."""
    parser = bench.add_parser(
        "view", help="latency and CPU of the live view (ssf view) beside a plain subscriber",
        description="Publish clouds at --rate for --duration seconds to a plain subscriber process (the baseline) "
        "and, in the same run, through an `ssf view` process to a Foxglove WebSocket client; report p50/p99 "
        "latencies, the share received, and the viewer's CPU and memory.")
    parser.add_argument("--points", type=int, default=65536, help="points per cloud (default 65536: one 64x1024 scan)")
    parser.add_argument("--rate", type=float, default=10.0, help="clouds per second (default 10)")
    parser.add_argument("--duration", type=float, default=20.0, help="seconds of publishing (default 20)")
    parser.add_argument("--json", metavar="FILE", help="also write the figures to FILE")
    parser.set_defaults(func=bench_view_command)


def bench_view_command(args: argparse.Namespace) -> int:
    """Handler of `ssf bench view`."""
    from ssf_common.checks import require_finite
    from ssf_common.errors import ConfigError
    from ssf_common.jsonio import dumps_strict, write_json
    from ssf_common.middleware import shutdown
    from ssf_common.paths import check_writable

    rate = require_finite(args.rate, "--rate", above=0.0, at_most=1000.0)
    duration = require_finite(args.duration, "--duration", above=0.0, at_most=3600.0)
    if not 1 <= args.points <= 2_000_000:
        raise ConfigError(f"--points must be from 1 to 2000000, got {args.points}")
    if int(rate * duration) < 1:
        raise ConfigError(f"--rate {rate:g} for --duration {duration:g} s sends no cloud; send at least one")
    if args.json:
        check_writable(args.json, "--json figures")
    result = run_bench_view(args.points, rate, duration, lambda text: print(f"bench view: {text}", file=sys.stderr))
    print(dumps_strict(asdict(result)))
    if args.json:
        write_json(args.json, asdict(result))
    shutdown()
    return 0
