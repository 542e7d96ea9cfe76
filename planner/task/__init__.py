"""Tasks above single plans: an assembly cycle (legs as ordinary plans, events between them), campaigns.

:mod:`~planner.task.schema` (the cycle document), :mod:`~planner.task.resolve` (made concrete),
:mod:`~planner.task.legs` (each leg's payload and cabin state), :mod:`~planner.task.cycle` (planning),
:mod:`~planner.task.check` (the independent re-check of a cycle profile document);
:mod:`~planner.task.campaign_schema` and :mod:`~planner.task.campaign` (a campaign's document and its
cycles composed in the cabin as it fills up), :mod:`~planner.task.order` (the install-order search),
:mod:`~planner.task.evidence` (what blocks a refused cycle). Running a campaign on the sweep executors is
the floor above the sweeps: :mod:`planner.campaign`.
"""
