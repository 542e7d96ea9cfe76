"""Install orders of a campaign: the given order, and the search for an order in which every cycle plans.

A campaign installs units one cycle at a time, each cycle planned in the cabin as it stands after the
installs before it. What a cycle meets depends on the *set* of units installed before it, not on their
order (every cycle starts and ends at the park posture), so the search runs over states S (the set of
campaign units installed so far) and asks an oracle whether unit u can be installed in state S:
``feasible(u, S)``. Each answer is a :class:`Verdict`; a refusal names what blocks the cycle (from its
evidence: the installed units within the clearance of the robot or its payload, see
:mod:`planner.task.evidence`).

Pruning rests on one assumption, stated in every report: **an installed unit only ever takes free space
away**, so a cycle refused with blockers B stays refused in every state that contains B (more installed
units never open a way). Then:

* a refusal of u in S blocked by units B (a subset of S) is a precedence constraint: u must be installed
  before at least one unit of B; with a single blocker X, "u before X";
* a state S from which some uninstalled unit u is known refused with blockers inside S is *dead*: u can
  never be installed afterwards, so no order through S completes, and no cycle is planned to learn it;
* a refusal of u in the empty state (blocked by the cabin itself, by the units installed before the
  campaign, or with no unit named) means no order exists: u cannot be installed even first.

The search (:func:`find_order`) is a depth-first search over states with a memo of dead states, so it is
complete over the orders it does not prune: it either returns an order in which every cycle was planned,
or proves that every order is dead or refused, with the constraints that prove it. Cycles of one state
are asked as a batch (the oracle plans them in parallel on the sweep executors); their answers come back
in the batch's order, so the search takes the same decisions whatever order the plans finish in (the
embedded and the Ray executors give the same order).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

__all__ = [
    "FindResult",
    "Oracle",
    "Query",
    "Verdict",
    "dead_reason",
    "find_order",
]

#: One question to the oracle: (unit id, campaign units installed before it).
Query = tuple[str, frozenset[str]]


@dataclass(frozen=True)
class Verdict:
    """The answer to ``feasible(unit, installed)``.

    Attributes:
        feasible: The cycle was planned (and passed the gate).
        blockers: Campaign units named by the refusal's evidence (empty when it names none; ``None`` when
            feasible).
        fixed: The refusal names only bodies that are there in every state (the cabin, units installed
            before the campaign, the dock's fixture) or nothing at all while no campaign unit was
            installed: the unit cannot be installed in any order.
        reason: The refusal's reason code (``None`` when feasible).
        message: One line: what blocks the cycle, or the cycle's duration.
    """

    feasible: bool
    blockers: frozenset[str] | None = None
    fixed: bool = False
    reason: str | None = None
    message: str = ""


#: Answers a batch of queries, one verdict per query, in the batch's order.
Oracle = Callable[[Sequence[Query]], list[Verdict]]


@dataclass
class FindResult:
    """What :func:`find_order` found.

    Attributes:
        order: Unit ids in an install order whose every cycle was planned, or ``None`` when none exists
            among the orders the search could not rule out.
        verdicts: Every answer the search had, by query.
        constraints: Learned "install u before one of B" facts: (u, B) for each refusal with blockers.
        states_explored: States whose candidates were asked.
        states_pruned: States found dead without planning (a known refusal inside them).
        reason: Why no order exists (``None`` when one was found).
        exhausted: The search stopped at its budget of cycles before deciding (``order`` is ``None``).
    """

    order: list[str] | None
    verdicts: dict[Query, Verdict] = field(default_factory=dict)
    constraints: list[tuple[str, frozenset[str]]] = field(default_factory=list)
    states_explored: int = 0
    states_pruned: int = 0
    reason: str | None = None
    exhausted: bool = False


class _Budget(Exception):
    """The search asked for more cycles than its budget allows."""


class _Search:
    def __init__(self, units: Sequence[str], oracle: Oracle, batch: int, max_cycles: int | None) -> None:
        self.units = list(units)
        self.oracle = oracle
        self.batch = max(1, int(batch))
        self.max_cycles = max_cycles
        self.verdicts: dict[Query, Verdict] = {}
        #: Refusals with blockers: unit -> list of blocker sets (u is refused in any state containing one).
        self.refused: dict[str, list[frozenset[str]]] = {u: [] for u in units}
        self.never: dict[str, Verdict] = {}
        self.dead: set[frozenset[str]] = set()
        self.explored = 0
        self.pruned = 0

    # ------------------------------------------------------------- knowledge
    def learn(self, query: Query, verdict: Verdict) -> None:
        self.verdicts[query] = verdict
        if verdict.feasible:
            return
        unit, installed = query
        if verdict.fixed or (not installed and not verdict.blockers):
            self.never.setdefault(unit, verdict)
            return
        blockers = (verdict.blockers or frozenset()) & installed
        # No campaign unit named although some were installed: the refusal holds (by the monotonicity
        # assumption) in every state containing all of them.
        self.refused[unit].append(blockers or installed)

    def known_refused(self, unit: str, state: frozenset[str]) -> bool:
        """Whether the unit is known refused in ``state`` (a blocker set of its refusals lies inside it)."""
        return unit in self.never or any(b <= state for b in self.refused[unit])

    def is_dead(self, state: frozenset[str]) -> bool:
        """No order through ``state`` completes: some unit not yet installed is refused in it for good."""
        if state in self.dead:
            return True
        if any(self.known_refused(u, state) for u in self.units if u not in state):
            self.dead.add(state)
            return True
        return False

    def ask(self, queries: list[Query]) -> None:
        new = [q for q in queries if q not in self.verdicts]
        if not new:
            return
        if self.max_cycles is not None and len(self.verdicts) + len(new) > self.max_cycles:
            new = new[: max(0, self.max_cycles - len(self.verdicts))]
            if not new:
                raise _Budget
        for query, verdict in zip(new, self.oracle(new), strict=True):
            self.learn(query, verdict)

    # ---------------------------------------------------------------- search
    def candidates(self, state: frozenset[str]) -> list[str]:
        """Units to try next from ``state``, in the given order, those whose next state is not dead."""
        out = []
        for u in self.units:
            if u in state or self.known_refused(u, state):
                continue
            if self.is_dead(state | {u}) and len(state) + 1 < len(self.units):
                self.pruned += 1
                continue
            out.append(u)
        return out

    def run(self, state: frozenset[str]) -> list[str] | None:
        """An order completing ``state`` (the units after it), or None when every continuation is dead."""
        if len(state) == len(self.units):
            return []
        if self.is_dead(state):
            return None
        self.explored += 1
        todo = self.candidates(state)
        while todo:
            chunk = [u for u in todo if (u, state) not in self.verdicts][: self.batch]
            self.ask([(u, state) for u in chunk])
            for u in list(todo):
                verdict = self.verdicts.get((u, state))
                if verdict is None:
                    break  # not asked yet: the next chunk
                todo.remove(u)
                if not verdict.feasible:
                    if self.is_dead(state):  # the refusal condemns this state: back up at once
                        return None
                    continue
                rest = self.run(state | {u})
                if rest is not None:
                    return [u, *rest]
            if self.is_dead(state):
                return None
        self.dead.add(state)
        return None


def find_order(
    units: Sequence[str],
    oracle: Oracle,
    *,
    batch: int = 2,
    max_cycles: int | None = None,
) -> FindResult:
    """Search an install order of ``units`` in which every cycle plans (see the module docstring).

    The root state is asked whole (every unit as the first install, one batch): it tells at once which
    units no order can install. Below it, each state's candidates are asked ``batch`` at a time in the
    given order (skipping those whose next state is provably dead); the first feasible candidate whose
    continuation completes wins. Answers are memoised by query, and a dead state is never entered again.

    Args:
        units: The campaign's unit ids in their listed order (the tie-break of the search).
        oracle: Plans a batch of queries (in parallel where it can) and answers in the batch's order.
        batch: Queries asked together below the root (the executor's parallel slots).
        max_cycles: Most cycles the search may ask for (``None``: no limit); past it the search stops
            undecided (``exhausted``).

    Returns:
        The order, or ``None`` with the reason none exists among the orders tried.
    """
    search = _Search(units, oracle, batch, max_cycles)
    empty: frozenset[str] = frozenset()
    order: list[str] | None = None
    exhausted = False
    try:
        search.ask([(u, empty) for u in search.units])
        if not search.never:
            order = search.run(empty)
    except _Budget:
        exhausted = True
    result = FindResult(
        order=order,
        verdicts=dict(search.verdicts),
        constraints=[(u, b) for u in search.units for b in search.refused[u]],
        states_explored=search.explored,
        states_pruned=search.pruned,
        exhausted=exhausted,
    )
    if order is None:
        result.reason = dead_reason(search.units, search.never, result.constraints, exhausted, max_cycles)
    return result


def dead_reason(
    units: Sequence[str],
    never: dict[str, Verdict],
    constraints: Sequence[tuple[str, frozenset[str]]],
    exhausted: bool = False,
    max_cycles: int | None = None,
) -> str:
    """Why no order was found, in one paragraph: units no order installs, or the constraints that clash."""
    if exhausted:
        return (
            f"the search stopped at its budget of {max_cycles} cycles before it found an order or ruled "
            "every one out"
        )
    if never:
        parts = [f"unit {u} cannot be installed even first ({v.message})" for u, v in never.items()]
        return "; ".join(parts)
    pairs = sorted({(u, next(iter(b))) for u, b in constraints if len(b) == 1})
    must = [f"{u} before {x}" for u, x in pairs]
    clash = [f"{u} before {x} and {x} before {u}" for u, x in pairs if (x, u) in pairs and u < x]
    text = "every order tried has a cycle refused"
    if clash:
        text += f": the refusals require {'; '.join(clash)}"
    elif must:
        text += f"; the refusals require {', '.join(must)}, and no order meets them all"
    return text
