#!/usr/bin/env bash
# Build graspd's container image: `scripts/image.sh [TAG]` (default graspd:latest), `scripts/image.sh --prepare`
# (only make podman and the base image ready).  Docker builds the Dockerfile as it is; with podman this script
# first makes the machine able to: installs podman, runc and debootstrap from Debian when missing (as root), sets
# containers.conf's default_ulimits empty when that file is absent, and when debian:bookworm-slim can be neither
# found nor pulled (no registry reachable) makes it from Debian's packages with debootstrap, trimmed like the
# registry's slim image (no apt lists, .deb cache, docs, man pages or locales).  CONTEXT=DIR builds another
# checkout (e.g. a `git archive HEAD` export) instead of this one; ENGINE=docker|podman picks the engine.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BASE=docker.io/library/debian:bookworm-slim
PREPARE_ONLY=0
cleanup=()
trap 'rm -rf "${cleanup[@]}"' EXIT
TAG=graspd:latest
for arg in "$@"; do
    case "$arg" in
        --prepare) PREPARE_ONLY=1 ;;
        -h|--help) sed -n "2,9p" "$0"; exit 0 ;;
        *) TAG="$arg" ;;
    esac
done

if [[ -z "${ENGINE:-}" ]]; then
    if command -v podman >/dev/null; then ENGINE=podman
    elif command -v docker >/dev/null; then ENGINE=docker
    else ENGINE=podman
    fi
fi

if [[ "$ENGINE" == docker ]]; then
    [[ "$PREPARE_ONLY" == 1 ]] && exit 0
    exec docker build -t "$TAG" "${CONTEXT:-$ROOT}"
fi

# cgroup v1 (no cgroup.controllers): crun refuses it, runc is needed
cgroup_v1=0
[[ -f /sys/fs/cgroup/cgroup.controllers ]] || cgroup_v1=1
if ! command -v podman >/dev/null || { [[ "$cgroup_v1" == 1 ]] && ! command -v runc >/dev/null; }; then
    if [[ "$(id -u)" != 0 ]] || ! command -v apt-get >/dev/null; then
        echo "podman (and runc on this cgroup v1 host) missing, cannot be installed here (needs root, apt-get)" >&2
        exit 3
    fi
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq podman runc debootstrap >/dev/null
fi
if [[ "$(id -u)" == 0 && ! -e /etc/containers/containers.conf ]]; then
    # podman's default ulimits (nofile 1048576) exceed what these machines allow a container
    mkdir -p /etc/containers
    printf '[containers]\ndefault_ulimits = []\n' > /etc/containers/containers.conf
fi

if ! podman image exists "$BASE" && ! timeout 300 podman pull -q "$BASE" >/dev/null 2>&1; then
    if ! command -v debootstrap >/dev/null; then
        if [[ "$(id -u)" != 0 ]] || ! command -v apt-get >/dev/null; then
            echo "$BASE cannot be pulled and debootstrap cannot be installed (needs root and apt-get)" >&2
            exit 3
        fi
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq debootstrap >/dev/null
    fi
    rootfs="$(mktemp -d)"
    cleanup+=("$rootfs")
    debootstrap --variant=minbase bookworm "$rootfs" http://deb.debian.org/debian >/dev/null
    cat > "$rootfs/etc/apt/sources.list" <<'EOF'
deb http://deb.debian.org/debian bookworm main
deb http://deb.debian.org/debian bookworm-updates main
deb http://deb.debian.org/debian-security bookworm-security main
EOF
    rm -rf "$rootfs"/var/lib/apt/lists/* "$rootfs"/var/cache/apt/*.bin "$rootfs"/var/cache/apt/archives/*.deb \
        "$rootfs"/usr/share/doc/* "$rootfs"/usr/share/man/* "$rootfs"/usr/share/info/* "$rootfs"/usr/share/locale/*
    tar -C "$rootfs" -c . | podman import -q --change 'CMD ["bash"]' - "$BASE" >/dev/null
    echo "made $BASE with debootstrap (no registry reachable)" >&2
fi
[[ "$PREPARE_ONLY" == 1 ]] && exit 0

# runc: crun refuses cgroup v1 hosts like these; --network=host: RUN steps reach PyPI and Debian through the host;
# --format docker: keeps the HEALTHCHECK (the OCI image format has no field for it)
runtime=()
command -v runc >/dev/null && runtime=(--runtime runc)
# A host whose HTTPS goes through an intercepting proxy names its CA in PIP_CERT: the build stage's pip is shown it
# through build-time mounts (a pip.conf and the CA file) while the build stage alone is built.  Their contents are
# in no layer, but their empty mount points are, so the final stage is built without them, from the cached build
# stage (mounts are not part of a layer's cache key).
build=(podman "${runtime[@]}" build --network=host --format docker)
if [[ -z "${CONTEXT:-}" ]] && git -C "$ROOT" rev-parse --git-dir >/dev/null 2>&1; then
    # one snapshot of the checkout (tracked files and untracked ones git does not ignore, as they are now), so that
    # both builds below see the same files however the checkout changes meanwhile
    CONTEXT="$(mktemp -d)"
    cleanup+=("$CONTEXT")
    git -C "$ROOT" ls-files -z --cached --others --exclude-standard \
        | tar -C "$ROOT" --null --no-recursion --ignore-failed-read -T - -cf - 2>/dev/null \
        | tar -C "$CONTEXT" -xf -
fi
if [[ -n "${PIP_CERT:-}" && -f "$PIP_CERT" ]]; then
    pipconf="$(mktemp)"
    cleanup+=("$pipconf")
    printf '[global]\ncert = /run/graspd-build-ca.crt\n' > "$pipconf"
    chmod 644 "$pipconf"
    "${build[@]}" -v "$PIP_CERT:/run/graspd-build-ca.crt:ro" -v "$pipconf:/etc/pip.conf:ro" --target build \
        "${CONTEXT:-$ROOT}"
fi
"${build[@]}" -t "$TAG" "${CONTEXT:-$ROOT}"
