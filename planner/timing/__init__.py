"""Geometric paths, time-parameterisation (the jerk-limited LP, TOPP-RA) and sampled drive profiles."""
