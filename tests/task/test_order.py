"""The order search against ground truth: random blocking relations, every order checked by brute force.

The oracle is a model of a cabin that fills up: unit u is refused in state S exactly when S contains one of
its blocker sets (the monotonicity the search assumes), and its refusal names the blockers present. The
search must find an order whenever one exists (checked over every permutation), return only orders whose
every cycle is feasible, and never ask the same question twice.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np
import pytest

from planner.task.order import Query, Verdict, find_order


class ModelOracle:
    """u refused in S iff some blocker set of u lies in S; ``never``: refused even in the empty cabin."""

    def __init__(self, blocks: dict[str, list[frozenset[str]]], never: frozenset[str] = frozenset()) -> None:
        self.blocks = blocks
        self.never = never
        self.asked: list[Query] = []
        self.batches: list[int] = []

    def feasible(self, unit: str, state: frozenset[str]) -> bool:
        return unit not in self.never and not any(b <= state for b in self.blocks.get(unit, []))

    def __call__(self, queries: Sequence[Query]) -> list[Verdict]:
        self.batches.append(len(queries))
        out = []
        for unit, state in queries:
            self.asked.append((unit, state))
            if self.feasible(unit, state):
                out.append(Verdict(True, message="planned"))
                continue
            named = frozenset().union(*[b for b in self.blocks.get(unit, []) if b <= state])
            out.append(Verdict(False, named, reason="no_path", message=f"{unit} blocked by {sorted(named)}"))
        return out


def brute_force(units: list[str], oracle: ModelOracle) -> bool:
    return any(
        all(oracle.feasible(u, frozenset(order[:k])) for k, u in enumerate(order))
        for order in itertools.permutations(units)
    )


def random_relation(rng: np.random.Generator, units: list[str]) -> dict[str, list[frozenset[str]]]:
    blocks: dict[str, list[frozenset[str]]] = {}
    for u in units:
        others = [v for v in units if v != u]
        for _ in range(int(rng.integers(0, 3))):
            size = int(rng.integers(1, 3))
            blocks.setdefault(u, []).append(frozenset(rng.choice(others, size=size, replace=False).tolist()))
    return blocks


@pytest.mark.parametrize("seed", range(40))
def test_an_order_is_found_exactly_when_one_exists(seed: int) -> None:
    rng = np.random.default_rng(seed)
    units = [f"U{k}" for k in range(int(rng.integers(3, 7)))]
    oracle = ModelOracle(random_relation(rng, units))
    result = find_order(units, oracle, batch=2)
    exists = brute_force(units, oracle)
    assert (result.order is not None) == exists, result.reason
    assert len(oracle.asked) == len(set(oracle.asked)), "a question asked twice"
    if result.order is not None:
        assert sorted(result.order) == sorted(units)
        for k, u in enumerate(result.order):  # every cycle of the order was asked and is feasible
            assert result.verdicts[(u, frozenset(result.order[:k]))].feasible
    else:
        assert result.reason and "every order tried has a cycle refused" in result.reason
    # The whole search never asks more than every (unit, state) pair there is.
    assert len(oracle.asked) <= len(units) * 2 ** (len(units) - 1)


def test_the_blocker_named_becomes_the_order_and_the_clash_is_said() -> None:
    units = ["A1", "B3", "C2"]
    # B3 installed blocks the way to A1: A1 must come first.
    oracle = ModelOracle({"A1": [frozenset({"B3"})]})
    result = find_order(["B3", "A1", "C2"], oracle, batch=2)
    assert result.order is not None and result.order.index("A1") < result.order.index("B3")
    assert ("A1", frozenset({"B3"})) in result.constraints

    # Each blocks the other: no order; the reason names the clash.
    clash = ModelOracle({"A1": [frozenset({"B3"})], "B3": [frozenset({"A1"})]})
    result = find_order(units, clash, batch=2)
    assert result.order is None and not brute_force(units, clash)
    assert "A1 before B3 and B3 before A1" in (result.reason or "")


def test_a_unit_refused_in_the_empty_cabin_ends_the_search_at_the_root() -> None:
    units = ["A1", "B3", "C2", "D4"]
    oracle = ModelOracle({}, never=frozenset({"C2"}))
    result = find_order(units, oracle, batch=2)
    assert result.order is None
    assert oracle.asked == [(u, frozenset()) for u in units]  # the root batch only
    assert "unit C2 cannot be installed even first" in (result.reason or "")


def test_dead_states_are_not_planned() -> None:
    # D blocks A; the given order puts D first, so every state holding D without A is dead at once.
    units = ["D", "B", "C", "A"]
    oracle = ModelOracle({"A": [frozenset({"D"})]})
    result = find_order(units, oracle, batch=1)
    assert result.order is not None and result.order.index("A") < result.order.index("D")
    # Once a refusal taught "A before D", no question is asked in a state that holds D but not A.
    learnt = next(k for k, (u, s) in enumerate(oracle.asked) if u == "A" and "D" in s)
    bad = [(u, s) for u, s in oracle.asked[learnt + 1 :] if "D" in s and "A" not in s]
    assert not bad, bad
    assert result.states_pruned > 0


def test_the_budget_stops_the_search_undecided() -> None:
    units = [f"U{k}" for k in range(5)]
    oracle = ModelOracle({"U0": [frozenset({"U1"})], "U1": [frozenset({"U0"})]})
    result = find_order(units, oracle, batch=2, max_cycles=3)
    assert result.order is None and result.exhausted and len(oracle.asked) <= 3
    assert "budget of 3 cycles" in (result.reason or "")


def test_same_answers_give_the_same_search_whatever_the_batch() -> None:
    rng = np.random.default_rng(7)
    units = [f"U{k}" for k in range(6)]
    blocks = random_relation(rng, units)
    runs = [find_order(units, ModelOracle(blocks), batch=2) for _ in range(2)]
    assert runs[0].order == runs[1].order and runs[0].verdicts == runs[1].verdicts
