"""varbot: teach a robot what your own spoken commands mean."""

__version__ = "0.1.0"
