"""Preloaded first by the job forkserver: it watches the server and exits when the server is gone.

Importing this module has that side effect on purpose (see :mod:`planner.core.lifeline`); nothing else imports
it. The job processes forked from the forkserver arm their own parent-death signal
(:func:`planner.core.lifeline.die_with_parent`), so they end with it.
"""

from __future__ import annotations

from planner.core.lifeline import watch_server_from_env

watch_server_from_env()
