#!/usr/bin/env bash
# Set up graspd on a fresh Debian machine: system libraries the wheels need, then a virtual
# environment in .venv with the server, the client, training (CPU torch), PostgreSQL support, the pybullet
# simulator (graspd-lab: the clutter benchmark), Ray (graspd-lab[cluster]: the lab's jobs as Ray tasks), the ROS 2
# node's DDS (graspd[ros2]) and dev tools.
# The PostgreSQL server package is for the tests: they start a throwaway server of their own (initdb/pg_ctl);
# haproxy too: tests/fleet run graspd servers behind it (examples/fleet/haproxy.cfg).
# Idempotent: re-running after a change to pyproject.toml reinstalls; otherwise it returns at once.
set -euo pipefail
cd "$(dirname "$0")/.."

PY=${PYTHON:-python3}
SYSTEM_PACKAGES="libusb-1.0-0 libgomp1 postgresql haproxy"   # the lab's open3d loads libusb; onnxruntime/torch: OpenMP;
                                                             # postgresql: the library-store tests run a real server;
                                                             # haproxy: tests/fleet run a fleet behind it

missing=""
for pkg in $SYSTEM_PACKAGES; do
  dpkg -s "$pkg" >/dev/null 2>&1 || missing="$missing $pkg"
done
if ! "$PY" -m venv --help >/dev/null 2>&1; then missing="$missing python3-venv"; fi
if [ -n "$missing" ]; then
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  echo "setup: installing system packages:$missing"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq $missing >/dev/null
fi

stamp=.venv/.graspd-setup
want=$(cat pyproject.toml client/pyproject.toml lab/pyproject.toml | sha256sum | cut -c1-16)
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then exit 0; fi

[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
# CPU build of torch (training and ONNX export only): pin it, a bare `torch` pulls a CUDA build.
.venv/bin/python -m pip install -q "torch==2.13.0"
# ./lab[cluster]: Ray, so that the lab's jobs can run as Ray tasks (--ray) and tests/lab/test_ray_jobs.py runs
.venv/bin/python -m pip install -q -e ./client -e ".[dev,postgres,ros2]" -e "./lab[cluster]"
echo "$want" > "$stamp"
echo "setup: ready (.venv)"
