# The RSMT service: `rsmt serve` on port 8000, CPU PyTorch, the default model inside.
#
#   docker build -t rsmt .                      # needs model/default_bundle (see docs/service.md, Docker)
#   docker run --rm -p 8000:8000 rsmt
#   docker run --rm -p 8000:8000 -v "$PWD/bundles:/models:ro" -e RSMT_MODELS=/models rsmt   # your own bundles
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1

# CPU PyTorch first, from its own index (the default index would bring the CUDA build, ~10x the size);
# the project's own `torch>=2.13.0,<2.14` is then already satisfied.
RUN pip install torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu

# The project, with model/default_bundle as package data, and the Python client it requires (rsmt-client,
# installed from its folder in the same command). The build stops here if that bundle is missing or does not
# load: the image must carry a working default model.
COPY . /src
RUN pip install /src/clients/python /src && rm -rf /src
RUN python -c "from model.inference.bundle import DEFAULT_BUNDLE, Bundle; Bundle.load(DEFAULT_BUNDLE)" \
 || { echo "model/default_bundle is missing or broken: train one (rsmt train recipe default-model --data DIR --run DIR --out model/default_bundle) before docker build" >&2; exit 1; }

RUN useradd --create-home --uid 10001 rsmt && mkdir /models && chown rsmt /models
USER rsmt
WORKDIR /home/rsmt
# Bundles to serve instead of the default model: mount them here and set RSMT_MODELS=/models.
VOLUME ["/models"]
EXPOSE 8000

# Ready = every model loaded and warmed (503 before that and while shutting down). No curl in slim.
HEALTHCHECK --interval=10s --timeout=3s --start-period=60s --retries=3 \
    CMD ["python", "-c", "import sys, urllib.request; sys.exit(urllib.request.urlopen('http://127.0.0.1:8000/v1/health/ready', timeout=2).status != 200)"]

# SIGTERM: readiness 503 and WebSockets closed (1001) at once, 1 s drain, then up to 8 s for in-flight
# requests (RSMT_SHUTDOWN_DRAIN_S, RSMT_SHUTDOWN_GRACE_S): inside `docker stop`'s default 10 s.
STOPSIGNAL SIGTERM
CMD ["rsmt", "serve", "--host", "0.0.0.0", "--port", "8000"]
