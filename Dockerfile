# MAGNET service image: the API (`magnet serve`) and the job workers (`magnet worker`).
# CPU by default. GPU workers: build on a CUDA base and take torch from the matching index, e.g.
#   docker build -t magnet-service:cuda \
#     --build-arg BASE_IMAGE=nvidia/cuda:12.6.3-cudnn-runtime-ubuntu24.04 \
#     --build-arg TORCH_INDEX=https://download.pytorch.org/whl/cu126 .
ARG BASE_IMAGE=python:3.11-slim
FROM ${BASE_IMAGE}

ARG TORCH_VERSION=2.13.0
ARG TORCH_INDEX=https://download.pytorch.org/whl/cpu
ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    MPLBACKEND=Agg \
    MAGNET_DATA_DIR=/data \
    PATH=/opt/venv/bin:$PATH

# CUDA base images come without Python; the python:* images have it already
RUN if ! command -v python3 >/dev/null 2>&1 || ! python3 -c "import venv, ensurepip" 2>/dev/null; then \
        apt-get update && apt-get install -y --no-install-recommends python3 python3-venv \
        && rm -rf /var/lib/apt/lists/*; \
    fi \
    && python3 -m venv /opt/venv \
    && pip install --upgrade pip \
    && pip install "torch==${TORCH_VERSION}" --index-url "${TORCH_INDEX}"

WORKDIR /src
COPY pyproject.toml setup.py ./
COPY models ./models
COPY jobqueue ./jobqueue
COPY service ./service
COPY worker ./worker
# a C compiler only while installing: setup.py builds the compiled helpers (models/quality/_fastmetrics.c,
# models/graph/_fastgraph.c, models/mesh/_fastmesh.c with its companion files)
RUN apt-get update && apt-get install -y --no-install-recommends gcc libc6-dev \
    && (python -c "import os, sys, sysconfig; sys.exit(not os.path.exists(sysconfig.get_paths()['include'] + '/Python.h'))" \
        || apt-get install -y --no-install-recommends python3-dev) \
    && pip install ".[neural,service]" \
    && (cd / && python -c "import models.quality._fastmetrics, models.graph._fastgraph, models.mesh._fastmesh") \
    && apt-get purge -y gcc libc6-dev && apt-get autoremove -y && rm -rf /var/lib/apt/lists/* \
    && useradd --system --create-home --uid 10001 magnet \
    && mkdir -p /data && chown magnet /data

USER magnet
WORKDIR /home/magnet
VOLUME ["/data"]
EXPOSE 8000
HEALTHCHECK --interval=30s --timeout=5s --start-period=30s \
    CMD python -c "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8000/healthz', timeout=4)" || exit 1
# API only; workers run as their own containers (`magnet worker`). `magnet serve` bound to 0.0.0.0
# refuses to start without API keys (MAGNET_API_KEYS or MAGNET_API_KEYS_FILE).
CMD ["magnet", "serve", "--host", "0.0.0.0", "--port", "8000", "--no-worker"]
