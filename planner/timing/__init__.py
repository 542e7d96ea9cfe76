"""Geometric paths, time-parameterisation (TOPP-RA) and sampled drive profiles."""
