#!/usr/bin/env bash
# A Debian bookworm base image with Python 3.11 (python3, python3-venv), made with debootstrap from Debian's
# own mirror, for machines that cannot pull python:3.11-slim from Docker Hub. Needs root, debootstrap and a
# running Docker daemon. The root filesystem is cached as a tarball, so a second run only imports it.
#
#   deploy/docker/debian-base.sh [TAG]          # default TAG: rsmt-base:bookworm
#   docker build --build-arg BASE=rsmt-base:bookworm -t rsmt .
#
# Cache: $RSMT_IMAGE_CACHE (default ~/.cache/rsmt-image). Mirror: $DEBIAN_MIRROR (default deb.debian.org).
set -euo pipefail
tag=${1:-rsmt-base:bookworm}
cache=${RSMT_IMAGE_CACHE:-"$HOME/.cache/rsmt-image"}
mirror=${DEBIAN_MIRROR:-http://deb.debian.org/debian}
packages=python3,python3-venv
tarball="$cache/bookworm-minbase-${packages//,/-}.tar"

if [ ! -s "$tarball" ]; then
  mkdir -p "$cache"
  root=$(mktemp -d "$cache/rootfs.XXXXXX")
  # debootstrap mounts /proc and /sys inside while it configures: never delete through a mount left behind.
  trap 'awk -v r="$root/" "index(\$2, r) == 1 {print \$2}" /proc/mounts | sort -r | xargs -r umount -l; rm -rf --one-file-system "$root"' EXIT
  echo "== debootstrap bookworm (minbase + $packages) into $root" >&2
  nice -n 10 debootstrap --variant=minbase --include="$packages" bookworm "$root" "$mirror" >&2
  # What Debian's own slim images leave out: package caches and lists, documentation, manuals, translations.
  rm -rf "$root"/var/cache/apt/* "$root"/var/lib/apt/lists/* "$root"/usr/share/doc/* "$root"/usr/share/man/* \
         "$root"/usr/share/locale/* "$root"/var/log/* "$root"/tmp/*
  tar -C "$root" --numeric-owner -cf "$tarball.part" .
  mv "$tarball.part" "$tarball"
fi
echo "== docker import $tarball as $tag" >&2
docker import --change 'CMD ["python3"]' --change 'ENV LANG=C.UTF-8' "$tarball" "$tag" >/dev/null
echo "$tag"
