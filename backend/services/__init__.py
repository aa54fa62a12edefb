"""Plain functions over a SQLAlchemy session: what the routes (and the workers) do with the data."""
