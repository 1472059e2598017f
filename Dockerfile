# graspd: the grasp-detection service (HTTP :8000, Zenoh peer on :7447), shipped models baked in.
# Build: docker build -t graspd .  (or `make image`: scripts/image.sh, podman too)
# Run: docker run -p 8000:8000 -v graspd-data:/var/lib/graspd graspd
# (the volume keeps the grasp-template library, an SQLite file, across containers; or set GRASPD_TEMPLATE_LIBRARY,
# postgresql+psycopg:// URLs work: the image has the postgres extra)
# Zenoh listens on the container's loopback only until you secure it: to reach it from the robot, add
#   -p 7447:7447 -e GRASPD_ZENOH_LISTEN='["tcp/0.0.0.0:7447"]' -e GRASPD_TOKEN=...   (and/or GRASPD_ZENOH_CONFIG
# with TLS and user/password, docs/deploy/security.md).  A non-loopback listener with no token and no
# authentication in the config refuses to start (GRASPD_ZENOH_ALLOW_ANONYMOUS=true overrides, trusted networks).
# Two stages: the first builds wheels of the server, the client and every dependency and installs them into a venv;
# the second holds that venv (no compiler, no pip, no pip cache, no sources), only the server (no lab: torch,
# pybullet, open3d) and models/.
# Debian bookworm's Python 3.11 in a virtual environment (/opt/venv, first on PATH), so the image builds from
# debian:bookworm-slim with stock docker or podman (scripts/image.sh: podman on machines with no registry).
# CI runs neither: tests/server/test_container_install.py replays the pip steps below in a venv, and
# tests/server/test_container_image.py (slow, root) builds and runs the image with podman.
FROM debian:bookworm-slim AS build

ENV DEBIAN_FRONTEND=noninteractive \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PATH=/opt/venv/bin:$PATH
RUN apt-get update \
    && apt-get install -y --no-install-recommends python3 python3-venv \
    && rm -rf /var/lib/apt/lists/* \
    && python3 -m venv /opt/venv
WORKDIR /src
COPY client/ client/
COPY pyproject.toml README.md ./
COPY service/ service/
# Wheels of graspd (the server distribution: no lab), graspd-client and all their dependencies (numba, llvmlite,
# onnxruntime and the rest have manylinux wheels for CPython 3.11: no compiler).
RUN pip wheel --wheel-dir /wheels ./client ".[postgres]"
# The server's venv, installed from those wheels alone; pip and setuptools leave it, so the image has no installer.
# No lab (graspd-lab: torch, pybullet, open3d): the service never imports it (tests/server/test_import_light.py).
RUN pip install --no-index --find-links /wheels graspd-client "graspd[postgres]"
RUN pip uninstall -y -q pip setuptools

FROM debian:bookworm-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    VIRTUAL_ENV=/opt/venv \
    PATH=/opt/venv/bin:$PATH

# Python and OpenMP (onnxruntime) only, and the build stage's venv: the same Debian Python at the same paths.  No
# open3d (nor its GL/EGL/X11 and libusb libraries): graspd reads PCD and PLY files with numpy; open3d is the lab's
# (bench/results/install-server-after.md: the sizes before and after).
RUN apt-get update \
    && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends python3 libgomp1 \
    && rm -rf /var/lib/apt/lists/* /var/cache/apt/*.bin /var/log/apt /var/log/dpkg.log

RUN useradd --create-home --uid 10001 --shell /usr/sbin/nologin graspd
RUN mkdir -p /var/lib/graspd && chown graspd:graspd /var/lib/graspd

COPY --from=build /opt/venv /opt/venv
WORKDIR /opt/graspd
COPY models/ models/

ENV GRASPD_MODELS_DIR=/opt/graspd/models \
    GRASPD_HOST=0.0.0.0 \
    GRASPD_PORT=8000 \
    GRASPD_DATA_DIR=/var/lib/graspd \
    GRASPD_ZENOH_LISTEN='["tcp/127.0.0.1:7447"]'

USER graspd
# numba's machine code for the hot loops, compiled now by the warm-up detection `graspd serve` runs before it says
# ready, into this user's cache (~/.cache/graspd/numba, 3 MB): a container on a machine with the build machine's
# CPU is ready in seconds instead of ~45 s of compiling; on another CPU the first start compiles its own.
RUN python -c "from graspd.server.settings import Settings; \
from graspd.server.services.registry import ModelRegistry; \
from graspd.server.services.warmup import warm_detection, warm_paths; \
s = Settings(); warm_paths(); \
warm_detection(ModelRegistry.load(s.resolved_models_dir(), s.default_model, s.model_threads, \
allow_unscored=s.allow_unscored, cascade=s.cascade_model or None))"
VOLUME /var/lib/graspd
EXPOSE 8000 7447
# Ready, not merely alive: /readyz answers 200 once the models are loaded and warmed up, 503 while starting,
# draining or without a usable model (its details need the token; the status code does not).  It asks the port
# GRASPD_PORT names, so a container run with another port stays healthy.
HEALTHCHECK --interval=15s --timeout=3s --start-period=60s --retries=3 \
    CMD ["python", "-c", "import os, sys, urllib.request; sys.exit(urllib.request.urlopen('http://127.0.0.1:%s/readyz' % os.environ.get('GRASPD_PORT', '8000'), timeout=2).status != 200)"]
STOPSIGNAL SIGTERM
CMD ["graspd", "serve"]
