#!/usr/bin/env bash
# deploy/build_base.sh: base images for deploy/Dockerfile and deploy/prometheus/Dockerfile built from the Debian
# mirror, for machines that reach a Debian mirror but no image registry (no Docker Hub). Needs root, podman and
# mmdebstrap (Debian: apt-get install podman mmdebstrap).
#
#   localhost/cmcl-debian:bookworm   Debian bookworm minbase + ca-certificates   (stands in for debian:bookworm-slim)
#   localhost/cmcl-python:3.11       the above + Debian's python3.11 and venv    (stands in for python:3.11-slim)
#
# Then build with `--build-arg BASE=localhost/cmcl-python:3.11` (deploy/Dockerfile) and
# `--build-arg BASE=localhost/cmcl-debian:bookworm` (deploy/prometheus/Dockerfile); docker-compose.yml passes
# them from CMCL_BASE_IMAGE / CMCL_DEBIAN_IMAGE. Where a registry is reachable none of this is needed: the
# Dockerfiles default to the official images. Existing images are kept unless --force is given.
set -euo pipefail
DEBIAN_IMAGE=${CMCL_DEBIAN_IMAGE:-localhost/cmcl-debian:bookworm}
PYTHON_IMAGE=${CMCL_BASE_IMAGE:-localhost/cmcl-python:3.11}
FORCE=${1:-}

if [ "$FORCE" = --force ] || ! podman image exists "$DEBIAN_IMAGE"; then
    tmp=$(mktemp -d)
    trap 'rm -rf "$tmp"' EXIT
    mmdebstrap --quiet --variant=minbase --include=ca-certificates bookworm "$tmp/rootfs.tar"
    podman import --change 'ENV=PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
        --change 'CMD=["/bin/bash"]' "$tmp/rootfs.tar" "$DEBIAN_IMAGE" >/dev/null
fi

if [ "$FORCE" = --force ] || ! podman image exists "$PYTHON_IMAGE"; then
    podman build --quiet --tag "$PYTHON_IMAGE" --build-arg "BASE=$DEBIAN_IMAGE" - >/dev/null <<'CONTAINERFILE'
ARG BASE
FROM $BASE
RUN apt-get update && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
        python3 python3-venv python-is-python3 \
    && rm -rf /var/lib/apt/lists/*
CONTAINERFILE
fi
podman image ls --format '{{.Repository}}:{{.Tag}} {{.Size}}' | grep -E "^(${DEBIAN_IMAGE}|${PYTHON_IMAGE}) "
