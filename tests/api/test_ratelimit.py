"""The per-tenant rate limit: one window per tenant in memory, or shared by every instance through Redis."""

from __future__ import annotations

import os
import socket
import time
import uuid

import pytest
from pydantic import ValidationError

from api.ratelimit import STORE_TIMEOUT_S, TenantRateLimiter
from api.settings import Settings

REDIS_URI = os.environ.get("CABINPLAN_TEST_REDIS_URI", "redis://127.0.0.1:6379/0")


def _redis_or_skip() -> None:
    import redis

    try:
        redis.Redis.from_url(REDIS_URI, socket_connect_timeout=1).ping()
    except Exception as exc:
        pytest.skip(f"no Redis server at {REDIS_URI} ({type(exc).__name__}: {exc})")


def test_memory_windows_are_per_instance_and_per_tenant() -> None:
    a, b = TenantRateLimiter("3 per 60 seconds"), TenantRateLimiter("3 per 60 seconds")
    assert [a.hit("t") for _ in range(3)] == [None] * 3
    wait = a.hit("t")
    assert wait is not None and 0.0 < wait <= 60.0
    assert a.hit("other") is None  # another tenant has its own window
    assert b.hit("t") is None  # another instance counts alone in memory


def test_redis_window_is_shared_by_every_instance() -> None:
    _redis_or_skip()
    namespace = f"cabinplan-test-{uuid.uuid4().hex[:12]}"
    a = TenantRateLimiter("5 per 60 seconds", REDIS_URI, namespace)
    b = TenantRateLimiter("5 per 60 seconds", REDIS_URI, namespace)
    try:
        allowed = [x.hit("t") is None for x in (a, b, a, b, a)]
        assert allowed == [True] * 5
        wait_a, wait_b = a.hit("t"), b.hit("t")  # the sixth request on either instance is refused
        assert wait_a is not None and wait_b is not None and 0.0 < wait_b <= 60.0
        assert a.hit("other") is None
        other_deployment = TenantRateLimiter("5 per 60 seconds", REDIS_URI, namespace + "-b")
        assert other_deployment.hit("t") is None  # its own namespace, its own window
        assert a.store_errors == b.store_errors == 0
    finally:
        a.storage.reset()


def test_a_store_that_does_not_answer_lets_requests_through() -> None:
    down = TenantRateLimiter("1 per 60 seconds", "redis://127.0.0.1:1/0")  # connection refused
    assert down.hit("t") is None and down.hit("t") is None
    assert down.store_errors == 2


def test_a_store_that_accepts_but_never_replies_is_given_up_on_quickly() -> None:
    """A frozen Redis (or a partition) must not hold requests: each waits at most the store timeout."""
    with socket.socket() as silent:
        silent.bind(("127.0.0.1", 0))
        silent.listen(8)
        port = silent.getsockname()[1]
        frozen = TenantRateLimiter("1 per 60 seconds", f"redis://127.0.0.1:{port}/0")
        t0 = time.monotonic()
        assert frozen.hit("t") is None
        waited = time.monotonic() - t0
    assert frozen.store_errors == 1
    assert waited < 4 * STORE_TIMEOUT_S + 1.0, waited


def test_settings_refuse_an_unknown_storage(tmp_path) -> None:
    with pytest.raises(ValidationError, match="rate_limit_storage_uri"):
        Settings(data_dir=tmp_path, rate_limit_storage_uri="mongodb://x")
    assert Settings(data_dir=tmp_path, rate_limit_storage_uri="redis://127.0.0.1:6379/0")
