"""core is the ground floor: every package may import it, and it imports none of the project and nothing
heavy, so that the API can apply the household's rules without loading the simulator or torch."""

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import core
from core.paths import REPO_ROOT


def test_core_imports_nothing_of_the_project_and_nothing_heavy() -> None:
    modules = sorted(f"core.{path.stem}" for path in Path(core.__file__).parent.glob("*.py"))
    script = textwrap.dedent(
        f"""
        import importlib, json, sys
        before = set(sys.modules)
        for name in {modules!r}:
            importlib.import_module(name)
        loaded = {{m.split(".")[0] for m in set(sys.modules) - before}}
        print(json.dumps(sorted(loaded - {{"core"}})))
        """
    )
    result = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=60, cwd=REPO_ROOT
    )
    assert result.returncode == 0, result.stderr[-3000:]
    forbidden = {
        "backend", "worker", "scene", "sim", "learning", "varbot", "bench",
        "torch", "pybullet", "gymnasium", "numpy", "sqlalchemy", "fastapi", "pydantic", "celery", "redis",
    }  # fmt: skip
    loaded = json.loads(result.stdout)
    assert not forbidden & set(loaded), loaded
    assert len(modules) >= 4, modules
