"""What a viewer of the scene is offered: no share button (Viser's would hand out a public link to a scene
that is shown through the app only), and the reward labelled in plain words rather than as a formula."""

from collections.abc import Iterator

import msgspec.msgpack
import pytest
import viser
import websockets.sync.client
import zstandard
from scene_helpers import SceneHousehold

from scene.access import SECRET_HEADER
from scene.service import SceneService


def viser_messages(frame: bytes) -> list[dict]:
    """One Viser 1.1 frame: its sizes, then zstd-compressed msgpack {"messages": [...], ...}, then buffers."""
    size, compressed = int.from_bytes(frame[:8], "little"), int.from_bytes(frame[8:16], "little")
    inner = zstandard.ZstdDecompressor().decompress(frame[16 : 16 + compressed], max_output_size=size)
    return list(msgspec.msgpack.decode(inner)["messages"])


@pytest.fixture
def first_messages(scene_household: SceneHousehold) -> Iterator[list[dict]]:
    """The messages a new viewer receives in its first seconds (the theme and the panel come first)."""
    service = SceneService(scene_household.household_id, fps=15)
    received: list[dict] = []
    try:
        with websockets.sync.client.connect(
            service.url.replace("http://", "ws://"),
            subprotocols=[f"viser-v{viser.__version__}"],  # type: ignore[list-item]
            additional_headers={SECRET_HEADER: service.secret},
            open_timeout=10,
        ) as viewer:
            try:
                while True:
                    message = viewer.recv(timeout=3)
                    assert isinstance(message, bytes)
                    received += viser_messages(message)
            except TimeoutError:
                pass
        yield received
    finally:
        service.server.stop()


def test_the_viewer_has_no_share_button(first_messages: list[dict]) -> None:
    themes = [m for m in first_messages if m["type"] == "ThemeConfigurationMessage"]
    assert themes and themes[-1]["show_share_button"] is False


def test_the_reward_is_labelled_in_plain_words(first_messages: list[dict]) -> None:
    labels = [str(m.get("props", {}).get("label")) for m in first_messages if m["type"] == "GuiNumberMessage"]
    assert "How close to the command" in labels, labels
    assert not any("f_I" in label for label in labels), labels
