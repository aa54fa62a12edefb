"""The ground floor: the data directory and the household's domain rules.

Plain Python (no torch, pybullet, web framework or database): every other package may import it, and it
imports none of them.
"""
