"""Tasks above single plans: an assembly cycle (legs as ordinary plans, events between them).

:mod:`~planner.task.schema` (the cycle document), :mod:`~planner.task.resolve` (made concrete),
:mod:`~planner.task.legs` (each leg's payload and cabin state), :mod:`~planner.task.cycle` (planning),
:mod:`~planner.task.check` (the independent re-check of a cycle profile document).
"""
