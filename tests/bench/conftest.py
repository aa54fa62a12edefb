"""Bench scripts import their helpers as siblings (`python bench/x.py` puts bench/ first on sys.path); the
tests import them the same way. Appended, so that no bench script's name shadows another module."""

import sys
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parents[2] / "bench"))
