"""Bench scripts import their helpers as siblings (`python bench/x.py` puts bench/ first on sys.path); the
tests import them the same way."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
