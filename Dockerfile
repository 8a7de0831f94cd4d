# The RSMT service: `rsmt serve` on port 8000, CPU PyTorch, the default model inside.
#
#   docker build -t rsmt .                      # needs model/default_bundle (see docs/service.md, Docker)
#   docker run --rm -p 8000:8000 rsmt
#   docker run --rm -p 8000:8000 -v "$PWD/bundles:/models:ro" -e RSMT_MODELS=/models rsmt   # your own bundles
#
# Build arguments (docs/deploy.md, The image):
#   BASE         any Debian-like image with Python 3.11 and its venv module (default python:3.11-slim); both
#                stages use it, so the virtual environment's python is the runtime's.
#   TORCH_INDEX  where the CPU torch 2.13.0 comes from (default PyTorch's CPU index: the default PyPI wheel
#                brings GBs of CUDA libraries).
# Offline: when deploy/docker/wheels/ holds wheels, everything is installed from that folder alone
# (pip --no-index), e.g. after
#   pip download -d deploy/docker/wheels torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu \
#       --extra-index-url https://pypi.org/simple ./clients/python . 'setuptools>=69' wheel 'async-timeout>=4.0.3'
# (docs/deploy.md, The image; deploy/docker/debian-base.sh makes a BASE where Docker Hub is out of reach).
ARG BASE=python:3.11-slim

# ---- build: one virtual environment, /opt/rsmt, with torch, the project and its client
FROM ${BASE} AS build
ARG TORCH_INDEX=https://download.pytorch.org/whl/cpu
ENV PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PATH=/opt/rsmt/bin:$PATH
RUN python3 -m venv /opt/rsmt
COPY deploy/docker/wheels/ /wheels/
# torch first, in its own layer: rebuilding after a code change does not fetch it again.
RUN if ls /wheels/*.whl >/dev/null 2>&1; then \
        pip install --no-index --find-links /wheels torch==2.13.0; \
    else \
        pip install torch==2.13.0 --index-url "$TORCH_INDEX"; \
    fi
# The project, with model/default_bundle as package data, and the Python client it requires (rsmt-client,
# installed from its folder in the same command); the project's `torch>=2.13.0,<2.14` is already satisfied.
COPY pyproject.toml README.md /src/
COPY clients/python/ /src/clients/python/
COPY model/ /src/model/
COPY service/ /src/service/
COPY rsmt_cli/ /src/rsmt_cli/
# Then out with what serving never loads: pip, torch's C++ headers and test programs, the libraries' own tests.
RUN if ls /wheels/*.whl >/dev/null 2>&1; then set -- --no-index --find-links /wheels; fi \
 && pip install "$@" /src/clients/python /src \
 && pip uninstall -y pip \
 && site=$(python -c "import sysconfig; print(sysconfig.get_path('purelib'))") \
 && rm -rf "$site/torch/include" "$site/torch/test" "$site"/torch/bin/test_* "$site"/torch/bin/*Test \
           "$site"/torch/bin/protoc* "$site/torch/share/cmake" \
 && find "$site" -type d -name tests -prune -exec rm -rf {} +
# The build stops here if the bundle is missing or does not load, or if the package left out one of its files
# (the built-in styles are a subfolder): the image must carry the whole working default model.
RUN python -c "from model.inference.bundle import DEFAULT_BUNDLE, Bundle; Bundle.load(DEFAULT_BUNDLE)" \
 || { echo "model/default_bundle is missing or broken: train one (rsmt train recipe default-model --data DIR --run DIR --out model/default_bundle) before docker build" >&2; exit 1; }
RUN cd /src/model/default_bundle && find . -type f | python -c "import sys; from model.inference.bundle import DEFAULT_BUNDLE as d; \
missing = [f for f in sys.stdin.read().split() if not (d / f).is_file()]; \
sys.exit(f'not installed from model/default_bundle (package-data in pyproject.toml): {missing}' if missing else 0)"

# ---- runtime: the base, the virtual environment, a user
FROM ${BASE}
ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PATH=/opt/rsmt/bin:$PATH
COPY --from=build /opt/rsmt /opt/rsmt
# uid and gid 10001, as deploy/kubernetes runs it (runAsUser, runAsGroup); numeric, so runAsNonRoot can check it.
RUN groupadd --gid 10001 rsmt && useradd --create-home --uid 10001 --gid 10001 rsmt && mkdir /models && chown rsmt /models
USER 10001:10001
WORKDIR /home/rsmt
# Bundles to serve instead of the default model: mount them here and set RSMT_MODELS=/models.
VOLUME ["/models"]
EXPOSE 8000

# Ready = every model loaded and warmed (503 before that and while shutting down). No curl in slim.
HEALTHCHECK --interval=10s --timeout=3s --start-period=60s --retries=3 \
    CMD ["python", "-c", "import sys, urllib.request; sys.exit(urllib.request.urlopen('http://127.0.0.1:8000/v1/health/ready', timeout=2).status != 200)"]

# SIGTERM: readiness 503 and WebSockets closed (1001) at once, 1 s drain, then up to 8 s for in-flight
# requests (RSMT_SHUTDOWN_DRAIN_S, RSMT_SHUTDOWN_GRACE_S): inside `docker stop`'s default 10 s; the process
# then exits 0. Raise `docker stop -t` (compose: stop_grace_period) if you raise those two.
STOPSIGNAL SIGTERM
CMD ["rsmt", "serve", "--host", "0.0.0.0", "--port", "8000"]
