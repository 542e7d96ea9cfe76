"""Seeded generators of cabins, scenarios, cycles and campaigns."""
