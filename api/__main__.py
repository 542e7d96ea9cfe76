"""``python -m api``: serve the HTTP API with uvicorn on the embedded defaults (127.0.0.1:8000).

On a loopback host a local-only default API key (tenant ``local``) is created on first start, kept in
``<data_dir>/local-api-key`` (mode 0600) and printed at every start-up, so ``make serve`` works at once.
Settings come from ``CABINPLAN_*`` environment variables (see :class:`api.settings.Settings`).
"""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Callable
from types import FrameType

import uvicorn

from api.app import create_app
from api.auth import LOCAL_TENANT, ensure_key, is_loopback, new_key
from api.settings import Settings


def local_key(settings: Settings) -> str:
    """The local default key (created once, file mode 0600)."""
    path = settings.data_dir / "local-api-key"
    if path.is_file():
        return path.read_text(encoding="utf-8").strip()
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    key = new_key()
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w", encoding="utf-8") as fh:
        fh.write(key + "\n")
    return key


def configure_logging() -> None:
    """Service logs as text lines; access logs (logger ``api.access``) as one JSON object a line."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    access = logging.getLogger("api.access")
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(message)s"))
    access.addHandler(handler)
    access.propagate = False


def main() -> None:
    """Start uvicorn; on loopback print the local default key first."""
    configure_logging()
    settings = Settings()
    app = create_app(settings)
    if is_loopback(settings.host):
        key = local_key(settings)
        ctx = app.state.ctx
        ctx.db.create_all()
        ensure_key(ctx, LOCAL_TENANT, key, "local default key")
        sys.stdout.write(
            f"cabinplan: local API key (tenant {LOCAL_TENANT!r}, loopback only): {key}\n"
            f"cabinplan: try: curl -H 'X-API-Key: {key}' http://{settings.host}:{settings.port}/api/v1/robots\n"
            f"cabinplan: operator page: http://{settings.host}:{settings.port}/viewer/ (key: as above)\n"
        )
        sys.stdout.flush()
    config = uvicorn.Config(app, host=settings.host, port=settings.port, log_level="info", access_log=False)
    _Server(config, app.state.ctx.waiters.close).run()


class _Server(uvicorn.Server):
    """uvicorn's server; on the exit signal the long polls answer at once (no wait for them to time out)."""

    def __init__(self, config: uvicorn.Config, on_exit: Callable[[], None]) -> None:
        super().__init__(config)
        self._on_exit = on_exit

    def handle_exit(self, sig: int, frame: FrameType | None) -> None:
        super().handle_exit(sig, frame)
        self._on_exit()


if __name__ == "__main__":
    main()
