# cabinplan HTTP service. Build: docker build -t cabinplan .
# Run:   docker run -p 8000:8000 -v cabinplan-data:/data -e CABINPLAN_ADMIN_KEY=<secret> cabinplan
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1

WORKDIR /app

# The exact, tested runtime set first (a layer that changes only with the lock file); the development
# pins (requirements-dev.lock: tests, lint, type-check) are not part of the image.
COPY requirements.lock ./
RUN python -m pip install --no-cache-dir -r requirements.lock

# Then the project itself, without resolving anything again.
COPY pyproject.toml README.md ./
COPY planner ./planner
COPY api ./api
RUN python -m pip install --no-cache-dir --no-deps . \
    && useradd --create-home --uid 10001 --shell /usr/sbin/nologin cabinplan \
    && mkdir -p /data \
    && chown cabinplan:cabinplan /data

USER cabinplan

ENV CABINPLAN_HOST=0.0.0.0 \
    CABINPLAN_PORT=8000 \
    CABINPLAN_DATA_DIR=/data \
    CABINPLAN_CACHE_DIR=/data/cache \
    NUMBA_CACHE_DIR=/data/cache/numba \
    MPLCONFIGDIR=/data/cache/matplotlib

VOLUME ["/data"]
EXPOSE 8000

HEALTHCHECK --interval=30s --timeout=5s --start-period=30s --retries=3 \
    CMD ["python", "-c", "import os, urllib.request; urllib.request.urlopen('http://127.0.0.1:' + os.environ.get('CABINPLAN_PORT', '8000') + '/api/v1/health', timeout=4)"]

CMD ["python", "-m", "api"]
