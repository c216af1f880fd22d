"""`ssf bench transport`: serialisation cost and two-process latency of PointCloud2 over the middleware."""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from ssf_common import messages
from ssf_common.middleware import QOS_SENSOR_DATA, Node, shutdown

BENCH_TOPIC = "/ssf_bench/points"
FIELDS = ("x", "y", "z", "intensity")


@dataclass(frozen=True)
class TransportBench:
    """What `ssf bench transport` reports (milliseconds unless named otherwise)."""

    serialize_ms_131k: float
    deserialize_ms_131k: float
    latency_p50_ms_8k: float
    latency_p99_ms_8k: float
    latency_p50_ms_131k: float
    latency_p99_ms_131k: float
    received_ratio_8k_best_effort: float
    received_ratio_131k_best_effort: float
    rate_hz: float
    duration_s: float
    backend: str


def make_points(num_points: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Random xyz and intensity, float32."""
    rng = np.random.default_rng(seed)
    return rng.uniform(-50, 50, (num_points, 3)).astype(np.float32), rng.uniform(0, 1, num_points).astype(np.float32)


def make_cloud(xyz: np.ndarray, intensity: np.ndarray, stamp_ns: int) -> Any:
    """What a driver does per scan: a PointCloud2 with x, y, z, intensity float32 from numpy arrays."""
    from ssf_common.pointcloud import xyz_to_cloud

    return xyz_to_cloud(xyz, messages.header(stamp_ns, "lidar"), intensity=intensity)


def decode_points(msg: Any) -> np.ndarray:
    """What a node does with a received cloud: a structured numpy view of its points."""
    from ssf_common.pointcloud import cloud_to_array

    return cloud_to_array(msg)


def time_serialization(num_points: int, repeats: int = 50) -> tuple[float, float]:
    """Median ms for numpy -> PointCloud2 -> CDR, and for CDR -> PointCloud2 -> numpy."""
    xyz, intensity = make_points(num_points)
    serialize_ms, deserialize_ms = [], []
    for i in range(repeats):
        start = time.perf_counter()
        raw = messages.serialize(make_cloud(xyz, intensity, i))
        serialize_ms.append((time.perf_counter() - start) * 1e3)
        start = time.perf_counter()
        points = decode_points(messages.deserialize(raw, "sensor_msgs/msg/PointCloud2"))
        deserialize_ms.append((time.perf_counter() - start) * 1e3)
        if points.shape[0] != num_points:
            raise RuntimeError(f"decoded {points.shape[0]} points, expected {num_points}")
    return statistics.median(serialize_ms), statistics.median(deserialize_ms)


class _BenchSubscriber(Node):
    def __init__(self, argv: list[str] | None = None) -> None:
        super().__init__("ssf_bench_subscriber", argv=argv)
        self.latencies_ms: list[float] = []
        self.create_subscription("sensor_msgs/msg/PointCloud2", BENCH_TOPIC, self.on_cloud, QOS_SENSOR_DATA)

    def on_cloud(self, msg: Any) -> None:
        decode_points(msg)
        self.latencies_ms.append((time.time_ns() - messages.stamp_ns(msg.header.stamp)) / 1e6)


def subscriber_main(expected: int, duration_s: float) -> None:
    """Child process: receive for duration + grace, print latencies as JSON."""
    node = _BenchSubscriber()
    print("ready", flush=True)
    deadline = time.monotonic() + duration_s + 3.0
    while time.monotonic() < deadline and len(node.latencies_ms) < expected:
        node.spin_once(0.05)
    print(json.dumps({"latencies_ms": node.latencies_ms}), flush=True)
    node.destroy_node()
    shutdown()


def measure_latency(num_points: int, rate_hz: float, duration_s: float) -> tuple[list[float], int]:
    """Publish clouds from this process to a subscriber process; return its latencies and the count sent."""
    count = int(rate_hz * duration_s)
    child = subprocess.Popen(
        [sys.executable, "-P", "-m", "ssf_common.bench_transport", "--subscriber", str(count), str(duration_s + 5.0)],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert child.stdout is not None
        child.stdout.readline()  # "ready"
        node = Node("ssf_bench_publisher")
        publisher = node.create_publisher("sensor_msgs/msg/PointCloud2", BENCH_TOPIC, QOS_SENSOR_DATA)
        deadline = time.monotonic() + 10.0
        while publisher.get_subscription_count() == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)  # let discovery settle both ways
        xyz, intensity = make_points(num_points)
        period = 1.0 / rate_hz
        next_send = time.monotonic()
        for _ in range(count):
            next_send += period
            publisher.publish(make_cloud(xyz, intensity, time.time_ns()))
            time.sleep(max(0.0, next_send - time.monotonic()))
        output, _ = child.communicate(timeout=duration_s + 30.0)
        node.destroy_node()
    finally:
        if child.poll() is None:
            child.kill()
    latencies = json.loads(output.strip().splitlines()[-1])["latencies_ms"]
    return latencies, count


def percentile(values: list[float], q: float) -> float:
    """q-th percentile, NaN for no values."""
    return float(np.percentile(values, q)) if values else float("nan")


def run_bench_transport(rate_hz: float = 10.0, duration_s: float = 20.0, progress: Any = None) -> TransportBench:
    """All transport figures of the issue's table."""
    say = progress or (lambda text: None)
    say("timing serialisation of 131072 points")
    serialize_ms, deserialize_ms = time_serialization(131072)
    say(f"latency, 8192 points, {rate_hz:g} Hz for {duration_s:g} s")
    lat_8k, sent_8k = measure_latency(8192, rate_hz, duration_s)
    say(f"latency, 131072 points, {rate_hz:g} Hz for {duration_s:g} s")
    lat_131k, sent_131k = measure_latency(131072, rate_hz, duration_s)
    from ssf_common.middleware.node import selected_backend

    return TransportBench(
        serialize_ms_131k=round(serialize_ms, 3),
        deserialize_ms_131k=round(deserialize_ms, 3),
        latency_p50_ms_8k=round(percentile(lat_8k, 50), 3),
        latency_p99_ms_8k=round(percentile(lat_8k, 99), 3),
        latency_p50_ms_131k=round(percentile(lat_131k, 50), 3),
        latency_p99_ms_131k=round(percentile(lat_131k, 99), 3),
        received_ratio_8k_best_effort=round(len(lat_8k) / sent_8k, 4),
        received_ratio_131k_best_effort=round(len(lat_131k) / sent_131k, 4),
        rate_hz=rate_hz,
        duration_s=duration_s,
        backend=selected_backend(),
    )


def bench_transport_command(args: argparse.Namespace) -> int:
    """Handler of `ssf bench transport`."""
    from ssf_common.checks import require_finite
    from ssf_common.errors import ConfigError
    from ssf_common.jsonio import dumps_strict, write_json
    from ssf_common.paths import check_writable

    rate = require_finite(args.rate, "--rate", above=0.0, at_most=10_000.0)
    duration = require_finite(args.duration, "--duration", above=0.0, at_most=86_400.0)
    if int(rate * duration) < 1:
        raise ConfigError(f"--rate {rate:g} for --duration {duration:g} s sends no cloud; send at least one")
    if args.json:
        check_writable(args.json, "--json figures")
    result = run_bench_transport(rate, duration,
                                 progress=lambda text: print(f"bench transport: {text}", file=sys.stderr))
    print(dumps_strict(asdict(result)))
    if args.json:
        write_json(args.json, asdict(result))
    shutdown()
    return 0


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "--subscriber":
        subscriber_main(int(sys.argv[2]), float(sys.argv[3]))
