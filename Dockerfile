# graspd: the grasp-detection service (HTTP :8000, Zenoh peer on :7447), shipped models baked in.
# Build: docker build -t graspd .    Run: docker run -p 8000:8000 -v graspd-data:/var/lib/graspd graspd
# (the volume keeps the grasp-template library, an SQLite file, across containers; or set GRASPD_TEMPLATE_LIBRARY,
# postgresql+psycopg:// URLs work: the image has the postgres extra)
# Zenoh listens on the container's loopback only until you secure it: to reach it from the robot, add
#   -p 7447:7447 -e GRASPD_ZENOH_LISTEN='["tcp/0.0.0.0:7447"]' -e GRASPD_TOKEN=...   (and/or GRASPD_ZENOH_CONFIG
# with TLS and user/password, README "Securing Zenoh").  A non-loopback listener with no token and no
# authentication in the config refuses to start (GRASPD_ZENOH_ALLOW_ANONYMOUS=true overrides, trusted networks).
# Two stages: the first builds wheels of the server, the client and every dependency; the second installs them
# with no compiler, no pip cache and no sources, and holds only the server (no lab: torch, pybullet, open3d) and
# models/.
# CI has no Docker engine: tests/server/test_container_install.py (slow) replays the pip steps below.
FROM python:3.11-slim AS build

ENV PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1
WORKDIR /src
COPY client/ client/
COPY pyproject.toml README.md ./
COPY service/ service/
# Wheels of graspd (the server distribution: no lab), graspd-client and all their dependencies.
RUN pip wheel --wheel-dir /wheels ./client ".[postgres]"

FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1

# OpenMP for onnxruntime.  No open3d (nor its GL/EGL/X11 and libusb libraries): graspd reads PCD and PLY files
# with numpy; open3d is the lab's (bench/results/install-server-after.md: the sizes before and after).
RUN apt-get update \
    && apt-get install -y --no-install-recommends libgomp1 \
    && rm -rf /var/lib/apt/lists/*

RUN useradd --create-home --uid 10001 --shell /usr/sbin/nologin graspd
RUN mkdir -p /var/lib/graspd && chown graspd:graspd /var/lib/graspd

# No lab (graspd-lab: torch, pybullet, open3d): the service never imports it (tests/server/test_import_light.py).
RUN --mount=type=bind,from=build,source=/wheels,target=/wheels \
    pip install --no-index --find-links /wheels graspd-client "graspd[postgres]"
WORKDIR /opt/graspd
COPY models/ models/

ENV GRASPD_MODELS_DIR=/opt/graspd/models \
    GRASPD_HOST=0.0.0.0 \
    GRASPD_PORT=8000 \
    GRASPD_DATA_DIR=/var/lib/graspd \
    GRASPD_ZENOH_LISTEN='["tcp/127.0.0.1:7447"]'

USER graspd
VOLUME /var/lib/graspd
EXPOSE 8000 7447
# Ready, not merely alive: /readyz answers 200 once the models are loaded and warmed up, 503 while starting,
# draining or without a usable model (its details need the token; the status code does not).
HEALTHCHECK --interval=15s --timeout=3s --start-period=60s --retries=3 \
    CMD ["python", "-c", "import sys, urllib.request; sys.exit(urllib.request.urlopen('http://127.0.0.1:8000/readyz', timeout=2).status != 200)"]
STOPSIGNAL SIGTERM
CMD ["graspd", "serve"]
