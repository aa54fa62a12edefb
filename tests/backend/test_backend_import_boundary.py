"""The API process stays small: importing and exercising it never loads torch, pybullet, learning/ or sim/."""

import subprocess
import sys
import textwrap


def test_the_api_never_imports_torch_or_pybullet(tmp_path, redis_socket) -> None:
    script = textwrap.dedent(
        f"""
        import io, os, sys
        os.environ.update(VARBOT_DATA_DIR={str(tmp_path)!r}, VARBOT_ENVIRONMENT="test",
                          VARBOT_SECRET_KEY="x" * 32, VARBOT_BROKER_URL="redis+socket://{redis_socket}",
                          VARBOT_PASSWORD_HASH_MEMORY_KIB="1024")
        import numpy as np, soundfile
        from fastapi.testclient import TestClient
        from backend.cli import upgrade, create_admin
        from backend.main import app

        upgrade("head")
        create_admin(username="alice", household="home", display_name=None, password="long password")
        client = TestClient(app)
        login = client.post("/api/v1/auth/login", json={{"username": "alice", "password": "long password"}})
        client.headers["X-CSRF-Token"] = login.json()["csrf_token"]
        robot = client.post("/api/v1/robots", json={{"name": "arm", "kind": "kuka-sim"}}).json()["id"]
        wav = io.BytesIO()
        soundfile.write(wav, 0.3 * np.sin(np.arange(44100) / 7), 44100, format="WAV")
        assert client.post("/api/v1/clips", files={{"file": ("a.wav", wav.getvalue())}}).status_code == 201
        capture = client.post(f"/api/v1/robots/{{robot}}/snapshots:capture", json={{"count": 2}})
        assert capture.status_code == 202
        for path in ("/api/v1/labels/next", "/api/v1/triplets/stats", "/health", "/api/v1/openapi.json"):
            assert client.get(path).status_code == 200, path
        forbidden = ("torch", "pybullet", "learning", "sim", "worker")
        heavy = sorted(m for m in sys.modules if m.split(".")[0] in forbidden)
        print("HEAVY", heavy)
        """
    )
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "HEAVY []" in result.stdout, result.stdout
