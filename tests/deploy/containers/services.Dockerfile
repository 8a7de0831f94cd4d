# Redis and HAProxy from Debian's packages, on the same debootstrap base as the rsmt image: compose.yaml's
# redis and haproxy images come from Docker Hub, which tests/deploy/test_image.py cannot reach.
ARG BASE
FROM ${BASE}
RUN apt-get update \
 && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends redis-server haproxy \
 && rm -rf /var/lib/apt/lists/* \
 && mkdir -p /data /usr/local/etc/haproxy
WORKDIR /data
