#!/usr/bin/env bash
# Record bags/sample again: the demo graph with a lighter LiDAR for 1 s, chosen topics (see bags/README.md).
set -euo pipefail
cd "$(dirname "$0")/.."
rm -rf bags/sample
.venv/bin/ssf launch scripts/sample_bag.yaml
.venv/bin/ssf bag info bags/sample
