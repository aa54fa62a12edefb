"""Only the app's proxy reaches the scene: Viser answers a request only when it carries this start's secret,
on 127.0.0.1 only, and the endpoint file that tells the app the secret is readable by its owner alone."""

import json
import socket
import stat
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
import viser
import websockets.sync.client

from scene import endpoint
from scene.access import SECRET_HEADER, guarded_viser_server, new_secret

VISER_PROTOCOL = f"viser-v{viser.__version__}"


@pytest.fixture
def guarded() -> Iterator[tuple[viser.ViserServer, str]]:
    secret = new_secret()
    server = guarded_viser_server(secret)
    try:
        yield server, secret
    finally:
        server.stop()


def test_a_request_without_this_starts_secret_is_refused(guarded: tuple[viser.ViserServer, str]) -> None:
    server, secret = guarded
    url = f"127.0.0.1:{server.get_port()}"
    for headers in ({}, {SECRET_HEADER: new_secret()}, {SECRET_HEADER: ""}):
        assert httpx.get(f"http://{url}/", headers=headers, timeout=10).status_code == 403
        with pytest.raises(websockets.exceptions.InvalidStatus) as refused:
            websockets.sync.client.connect(
                f"ws://{url}", subprotocols=[VISER_PROTOCOL], additional_headers=headers, open_timeout=10
            )
        assert refused.value.response.status_code == 403

    with_secret = {SECRET_HEADER: secret}
    assert httpx.get(f"http://{url}/", headers=with_secret, timeout=10).status_code == 200
    with websockets.sync.client.connect(
        f"ws://{url}", subprotocols=[VISER_PROTOCOL], additional_headers=with_secret, open_timeout=10
    ) as viewer:
        assert viewer.recv(timeout=10), "the scene's state streams to the one who has the secret"


def test_the_scene_listens_on_127_0_0_1_only(guarded: tuple[viser.ViserServer, str]) -> None:
    """Bound to every address, the port would also answer on 127.0.0.2 (and on the machine's own address)."""
    server, _ = guarded
    with pytest.raises(ConnectionRefusedError):
        socket.create_connection(("127.0.0.2", server.get_port()), timeout=5).close()


def test_the_endpoint_file_names_the_secret_and_only_its_owner_can_read_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("VARBOT_DATA_DIR", str(tmp_path))
    endpoint.announce("http://127.0.0.1:1234", household_id=3, secret="s3cret")
    written = endpoint.endpoint_file(household_id=3)
    assert stat.S_IMODE(written.stat().st_mode) == 0o600
    announced = json.loads(written.read_text())
    assert announced["headers"] == {SECRET_HEADER: "s3cret"} and announced["household_id"] == 3
    assert endpoint.announced(3) is not None and endpoint.announced(4) is None, "one file per household"
    endpoint.withdraw(household_id=3)
    assert not written.exists()
