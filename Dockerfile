# cabinplan HTTP service. Build: docker build -t cabinplan .
# Run:   docker run -p 8000:8000 -v cabinplan-data:/data -e CABINPLAN_ADMIN_KEY=<secret> cabinplan
#
# Two stages. The build stage has a C compiler: it installs the runtime pins and the project into a virtual
# environment, then builds what a plan would otherwise compile at first use (README "Start-up"): the
# ahead-of-time numba kernels for the architecture's baseline CPU (CABINPLAN_AOT_CPU=generic: portable,
# an image built on one machine runs on another), the native CasADi builds of the dynamics (plain -O1 C,
# no -march), numba's JIT cache of the robot kernels (NUMBA_CPU_NAME=generic, also portable) and the
# reference aisle cabin's clearance grid, all in one cache folder. The final stage is the slim image without a
# compiler: the environment and the cache folder, copied.
FROM python:3.11-slim AS build

ENV PYTHONDONTWRITEBYTECODE=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1

RUN apt-get update \
    && apt-get install -y --no-install-recommends gcc libc6-dev \
    && rm -rf /var/lib/apt/lists/*

WORKDIR /app

# The exact, tested runtime set first (a layer that changes only with the lock file); the development
# pins (requirements-dev.lock: tests, lint, type-check) are not part of the image.
RUN python -m venv /opt/venv
ENV PATH=/opt/venv/bin:$PATH
COPY requirements.lock ./
RUN python -m pip install --no-cache-dir -r requirements.lock

# Then the project itself, without resolving anything again.
COPY pyproject.toml README.md ./
COPY planner ./planner
COPY api ./api
RUN python -m pip install --no-cache-dir --no-deps .

# The builds, portable, into the folder the final image carries. The warm-up plans the service's own
# reference bay insertion (api.warmup): the native CasADi builds, numba's cache and the aisle cabin's grid.
ENV CABINPLAN_CACHE_DIR=/opt/cabinplan/cache \
    CABINPLAN_AOT_CPU=generic \
    NUMBA_CPU_NAME=generic \
    NUMBA_CACHE_DIR=/opt/cabinplan/cache/numba \
    MPLCONFIGDIR=/opt/cabinplan/cache/matplotlib
WORKDIR /tmp
RUN python -m planner.collision.kernels.build \
    && python -m planner.timing.acc_reference \
    && python -c "import api.warmup" \
    && python -c "from api.prebuilt import check; check()"

FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PATH=/opt/venv/bin:$PATH

RUN useradd --create-home --uid 10001 --shell /usr/sbin/nologin cabinplan \
    && mkdir -p /data \
    && chown cabinplan:cabinplan /data

COPY --from=build /opt/venv /opt/venv
COPY --from=build --chown=cabinplan:cabinplan /opt/cabinplan/cache /opt/cabinplan/cache

USER cabinplan
WORKDIR /home/cabinplan

# The cache folder is the image's own (new cabins' clearance grids are added to it while the container
# lives); the kernels and native builds in it need no compiler. NUMBA_CPU_NAME=generic: numba's cache
# built in the image is valid here (its index names the CPU it was compiled for).
ENV CABINPLAN_HOST=0.0.0.0 \
    CABINPLAN_PORT=8000 \
    CABINPLAN_DATA_DIR=/data \
    CABINPLAN_CACHE_DIR=/opt/cabinplan/cache \
    NUMBA_CPU_NAME=generic \
    NUMBA_CACHE_DIR=/opt/cabinplan/cache/numba \
    MPLCONFIGDIR=/opt/cabinplan/cache/matplotlib

VOLUME ["/data"]
EXPOSE 8000

HEALTHCHECK --interval=30s --timeout=5s --start-period=30s --retries=3 \
    CMD ["python", "-c", "import os, urllib.request; urllib.request.urlopen('http://127.0.0.1:' + os.environ.get('CABINPLAN_PORT', '8000') + '/api/v1/health', timeout=4)"]

CMD ["python", "-m", "api"]
