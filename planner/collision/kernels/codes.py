"""The codes and context slots the compiled kernels share with their Python callers (no numba import).

:mod:`.state` and :mod:`.walk` read these names inside compiled code, the collision world and the motion
walk in Python; keeping them here lets a plan served by the ahead-of-time build never import numba.
"""

from __future__ import annotations

#: Codes of :func:`.state.packed_check`.
CLEAR, INADMISSIBLE, UNDECIDED, NOT_FINITE, CONTACT = 0, 1, 2, 3, 4

#: Verdicts of :func:`.state.packed_valid`: invalid, valid (the obstacles still to check), not decided here
#: (a body needs a cabin probe and the world has no triangle tree: the caller's probes decide).
STATE_INVALID, STATE_VALID, STATE_UNDECIDED = 0, 1, 2

#: Codes of :func:`.walk.motion_walk`.
WALK_DONE, WALK_PROBE, WALK_FAIL, WALK_GROW = 0, 1, 2, 3
#: Slots of the walk's integer (``ci``) and float (``cf``) context arrays.
CI_TASK, CI_I, CI_PHASE, CI_N, CI_COUNT, CI_SLOT, CI_LEVELS, CI_CABIN, CI_PREV = range(9)
#: The count of the walk's own probes (a box against the cabin, :mod:`.mesh`).
CI_QUERIES = 9
CF_LAST, CF_E, CF_TSTOP, CF_CLEARANCE, CF_OWN, CF_MARGIN, CF_THRESHOLD, CF_TFAIL, CF_PROBE_PROVEN = range(9)
#: The smallest margin the walk may adapt to, the margin of the current step, the last proven state's E,
#: the smallest margin the walk stepped with.
CF_FLOOR, CF_LOCAL, CF_EPREV, CF_SMALLEST = 9, 10, 11, 12
CF_LEVEL0 = 13
#: Most probe levels the walk lists at one state (``cf[CF_LEVEL0:]``).
MAX_LEVELS = 16
CI_SIZE, CF_SIZE = 10, CF_LEVEL0 + MAX_LEVELS

#: The compiled tests on the cabin's triangles (:mod:`.mesh`) widen a box, and lower a distance, by this much
#: [m], so that rounding can only report a touch that is not there, or a distance below the true one.
ROUND_M = 1e-9

#: ``cover_walk`` state (``ci``): the task and piece it is at, the sample/task of a pending exact distance.
CW_TASK, CW_POS, CW_K, CW_PENDING, CW_SIZE = 0, 1, 2, 3, 4
#: ``cover_walk`` returns: every task covered (or its pieces left to the walk), or an exact distance needed.
COVER_DONE, COVER_EXACT = 0, 1
#: ``state`` entries, in the order evidence is asked for: nothing evaluated (the bound is only what other
#: samples imply), the certified bound, an FCL probe on the grown body, the exact FCL distance.
SPREAD, BOUND, PROBED, EXACT = 0, 1, 2, 3
