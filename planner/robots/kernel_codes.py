"""The codes and sizes of the robots' compiled pose kernels, without the kernels (no numba import).

The robot models (:class:`~planner.robots.geometry.CollisionModel`) name their kernel and its body kinds by
these values; the compiled kernels (:mod:`planner.robots.kernels`, :mod:`planner.robots.cabin8_kernels`)
read the same names, so a plan served by the ahead-of-time build of the kernels never imports numba.
"""

from __future__ import annotations

#: Kernel codes (``CollisionModel.kernel``).
CABIN8 = 1

#: Length of cabin8's kernel parameters: the MDH table (4 x 6: alpha, a, theta offset, d offset, joint
#: index, revolute 1/0) then the stage lengths L1, L2, L3, L4.
CABIN8_PARAMS = 28
#: Body kinds of cabin8's ``body_poses`` (the order of ``planner.robots.cabin8_geometry.BODY_NAMES``).
CABIN8_KIND_CODES = {
    "carriage": 0,
    "link_ab": 1,
    "link_cd": 2,
    "link_ef": 3,
    "platform": 4,
    "column": 5,
    "arm": 6,
    "slide": 7,
    "payload": 8,
}
