"""Documents and pictures of results: the JSON output contract and the PNG plots (no math here)."""
