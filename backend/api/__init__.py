"""HTTP routes, all under /api/v1."""
