"""meshio."""
