# graspd: the grasp-detection service (HTTP :8000, Zenoh peer on :7447), shipped models baked in.
# Build: docker build -t graspd .    Run: docker run -p 8000:8000 -v graspd-data:/var/lib/graspd graspd
# (the volume keeps the grasp-template library, an SQLite file, across containers; or set GRASPD_TEMPLATE_LIBRARY,
# postgresql+psycopg:// URLs work: the image has the postgres extra)
# Zenoh listens on the container's loopback only until you secure it: to reach it from the robot, add
#   -p 7447:7447 -e GRASPD_ZENOH_LISTEN='["tcp/0.0.0.0:7447"]' -e GRASPD_TOKEN=...   (and/or GRASPD_ZENOH_CONFIG
# with TLS and user/password, README "Securing Zenoh").  A non-loopback listener with no token and no
# authentication in the config refuses to start (GRASPD_ZENOH_ALLOW_ANONYMOUS=true overrides, trusted networks).
# CI has no Docker engine: tests/server/test_container_install.py (slow) replays the pip steps below.
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1

# open3d's shared libraries: OpenMP, libusb (RealSense IO), and the GL/EGL/X11 stubs it links against.
RUN apt-get update \
    && apt-get install -y --no-install-recommends libusb-1.0-0 libgomp1 libgl1 libegl1 libx11-6 \
    && rm -rf /var/lib/apt/lists/*

RUN useradd --create-home --uid 10001 --shell /usr/sbin/nologin graspd
RUN mkdir -p /var/lib/graspd && chown graspd:graspd /var/lib/graspd

WORKDIR /opt/graspd
COPY client/ client/
RUN pip install ./client
COPY pyproject.toml README.md ./
COPY service/ service/
# No lab (graspd-lab: torch, pybullet): the service never imports it (tests/server checks the import).
RUN pip install ".[postgres]"
COPY models/ models/

ENV GRASPD_MODELS_DIR=/opt/graspd/models \
    GRASPD_HOST=0.0.0.0 \
    GRASPD_PORT=8000 \
    GRASPD_DATA_DIR=/var/lib/graspd \
    GRASPD_ZENOH_LISTEN='["tcp/127.0.0.1:7447"]'

USER graspd
VOLUME /var/lib/graspd
EXPOSE 8000 7447
HEALTHCHECK --interval=15s --timeout=3s --start-period=60s --retries=3 \
    CMD ["python", "-c", "import sys, urllib.request; sys.exit(urllib.request.urlopen('http://127.0.0.1:8000/healthz', timeout=2).status != 200)"]
STOPSIGNAL SIGTERM
CMD ["graspd", "serve"]
