"""The names of the timing stages and the default rule: the vocabulary below every floor.

The registry of the stages (what each name builds, whether it binds the drive jerk limits) is
:mod:`planner.timing.stages`; the names and the rule that picks one when a scenario gives none live here,
on the ground floor, because the robot models (which sit below timing) report their default
(``summary()["default_timing"]``) and the scenario schema spells the names in its ``options.timing``.
The registry checks on import that it has exactly one entry per name.
"""

from __future__ import annotations

from typing import Final, Literal

#: A timing stage's name, as a scenario's ``options.timing`` spells it.
TimingName = Literal["jerk_limited", "acceleration_limited"]

#: Every drive's jerk within its limit (the LP of :mod:`planner.timing.jerk`), the path kept exactly.
JERK_LIMITED: Final[TimingName] = "jerk_limited"
#: TOPP-RA alone (:mod:`planner.timing.toppra`): velocity, acceleration and force limits, acceleration steps.
ACCELERATION_LIMITED: Final[TimingName] = "acceleration_limited"


def default_timing(has_jerk_limits: bool) -> TimingName:
    """The timing stage of a scenario that names none: jerk-limited when the robot has jerk limits.

    Without jerk limits in the robot description the default is acceleration-limited (TOPP-RA alone).
    On the reference suite the jerk-limited law lasts 1.02-1.07 times the acceleration-limited one
    (median 1.045, ``bench.timing``): the planner's corner blends are curvature-continuous (C2), so the
    jerk limits cost only the acceleration ramps.
    """
    return JERK_LIMITED if has_jerk_limits else ACCELERATION_LIMITED
