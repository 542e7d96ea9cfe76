"""HTTP service (FastAPI) in front of the planner; see the README for its endpoints."""
