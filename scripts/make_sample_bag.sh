#!/usr/bin/env bash
# Record bags/sample/recording again: the demo graph with a lighter LiDAR for 1 s (see bags/README.md).
set -euo pipefail
cd "$(dirname "$0")/.."
rm -rf bags/sample/recording
.venv/bin/ssf launch bags/sample/graph.yaml
.venv/bin/ssf bag info bags/sample/recording
