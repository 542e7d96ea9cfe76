"""Planning: the stages from a resolved scenario to a validated drive profile.

:mod:`~planner.plan.context` (PlanContext, Clearances, SearchPreset) is what every stage shares;
:mod:`~planner.plan.pipeline` calls the stages in order: :mod:`~planner.plan.endpoints`,
:mod:`~planner.plan.targets` (with :mod:`~planner.plan.goals`), :mod:`~planner.plan.compensate`,
:mod:`~planner.plan.search` (with :mod:`~planner.plan.connect`, :mod:`~planner.plan.transit`,
:mod:`~planner.plan.shortcut` and :mod:`~planner.plan.ompl_adapter`, the only module that imports OMPL),
:mod:`~planner.plan.smooth`, :mod:`~planner.plan.retime` and :mod:`~planner.plan.report`.
:mod:`~planner.plan.pose_path` plans pprs6's pose paths through the same timing stage and gate.
"""
