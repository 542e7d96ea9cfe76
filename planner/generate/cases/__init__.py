"""Generated cases: one module per goal kind, the clutter, the hatch, and the draw that composes them.

:mod:`.bay` and :mod:`.shelf` place pose goals (drive goals in :mod:`.endpoints`, with the starts);
:mod:`.clutter` draws ring frames, stringers, ducts and brackets, :mod:`.hatch` a passable bulkhead, and
:mod:`.draw` composes them in the order the case's generator is consumed.

Case ``index`` of ``seed`` is drawn from its own generator (``default_rng([seed, index])``, with the
family's tag as a third word for the families other than ``mixed``, whose goal kind is drawn once from
``default_rng([seed, index, tag, 1])``), redrawn until a draw passes the checks, so it is the same
whatever the count, and the same seed gives the same bytes.
"""

from __future__ import annotations

import numpy as np

from planner.generate.cases.common import first_valid
from planner.generate.cases.draw import draw_case, goal_kind
from planner.generate.families import FAMILIES
from planner.generate.options import GeneratedCase, GeneratorOptions


def generate_case(seed: int, index: int, options: GeneratorOptions | None = None) -> GeneratedCase:
    """Case ``index`` of ``seed``: drawn from its own generator until a draw passes the checks.

    Raises:
        RuntimeError: no valid draw within ``options.max_attempts`` (not seen with the defaults).
    """
    opts = options or GeneratorOptions()
    family = FAMILIES[opts.family]
    rng = np.random.default_rng([seed, index] if family.tag is None else [seed, index, family.tag])
    # A family's case keeps its goal kind through its redraws, so the kinds come in the family's weights
    # (the mixed family draws one at each attempt: kinds that redraw more often come less often).
    kind = (
        None
        if family.tag is None
        else goal_kind(np.random.default_rng([seed, index, family.tag, 1]), opts, family)
    )
    attempts = family.max_attempts if opts.max_attempts is None else opts.max_attempts
    return first_valid(
        lambda: draw_case(seed, index, rng, opts, family, kind), attempts, f"case {index} of seed {seed}"
    )


def generate_cases(seed: int, count: int, options: GeneratorOptions | None = None) -> list[GeneratedCase]:
    """Cases 0..count-1 of ``seed``."""
    return [generate_case(seed, i, options) for i in range(count)]


__all__ = ["generate_case", "generate_cases"]
