"""Suite-wide settings: tests never write into the real data directory."""

import os
import tempfile

# Set before any project module reads it. Individual tests may point it elsewhere with monkeypatch.
os.environ["VARBOT_DATA_DIR"] = tempfile.mkdtemp(prefix="varbot-test-data-")
os.environ.setdefault("VARBOT_ENVIRONMENT", "test")
