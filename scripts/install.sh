#!/usr/bin/env bash
# Install SSF-PAN and everything it needs into .venv (system libraries through apt when missing).
set -euo pipefail
cd "$(dirname "$0")/.."

python3 - <<'PY' || { echo "install: SSF-PAN needs Python 3.11 or newer as python3" >&2; exit 1; }
import sys
sys.exit(0 if sys.version_info >= (3, 11) else 1)
PY

missing=()
ldconfig -p | grep -q 'libusb-1.0.so.0' || missing+=(libusb-1.0-0)   # Open3D
ldconfig -p | grep -q 'libgomp.so.1' || missing+=(libgomp1)          # Open3D, torch
python3 -c 'import ensurepip, venv' 2>/dev/null || missing+=(python3-venv)
if ((${#missing[@]})); then
  echo "install: system packages ${missing[*]}" >&2
  sudo=""
  [ "$(id -u)" -ne 0 ] && sudo="sudo"
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "${missing[@]}" >/dev/null
fi

[ -x .venv/bin/python ] || python3 -m venv .venv
echo "install: Python packages into .venv (first time takes a few minutes)" >&2
.venv/bin/python -m pip install --quiet --disable-pip-version-check -e ".[test,ray]"
