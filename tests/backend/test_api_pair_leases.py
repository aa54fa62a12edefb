"""Pair leases: a pair handed to one member is not handed to another while they answer it, whether the two
requests reach one API process or two (the leases live in Redis), and in one process while Redis is away."""

import json
import os
import subprocess
import sys
import threading
from itertools import product

import pytest
from apitest_helpers import make_robot, make_wav, upload_clip, upload_snapshot

OTHER_MEMBER = 999_999  # a member labelling through another API process

# Another API process: it claims the pairs it is sent (one JSON list per line) after releasing its last ones.
_OTHER_PROCESS = """
import json, sys
from backend.services.pair_leases import pair_leases
held = []
for line in sys.stdin:
    for pair in held:
        pair_leases.release(pair)
    held = [tuple(pair) for pair in json.loads(line)]
    print(json.dumps([pair_leases.claim(pair, {other}) for pair in held]), flush=True)
"""


@pytest.fixture
def pairs(admin, member) -> list[tuple[int, int, int]]:
    robot = make_robot(admin)
    snapshots = [upload_snapshot(member, robot, seed=i).json()["id"] for i in range(3)]
    clips = [
        upload_clip(member, make_wav(frequency=f), name=n).json()["id"] for f, n in ((300, "l"), (600, "r"))
    ]
    return [(member.household_id, s, c) for s, c in product(snapshots, clips)]


@pytest.fixture
def other_process():  # type: ignore[no-untyped-def]
    process = subprocess.Popen(
        [sys.executable, "-c", _OTHER_PROCESS.format(other=OTHER_MEMBER)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        env=os.environ.copy(),  # the same VARBOT_BROKER_URL: the test's Redis
    )

    def claim(pairs: list[tuple[int, int, int]]) -> list[bool]:
        process.stdin.write(json.dumps(pairs) + "\n")  # type: ignore[union-attr]
        process.stdin.flush()  # type: ignore[union-attr]
        return json.loads(process.stdout.readline())  # type: ignore[union-attr]

    yield claim
    process.stdin.close()  # type: ignore[union-attr]
    process.wait(10)


def asked(person) -> tuple[int, int, int]:  # type: ignore[no-untyped-def]
    pair = person.client.get("/api/v1/labels/next").json()
    return (person.household_id, pair["snapshot"]["id"], pair["clip"]["id"])


def test_a_pair_held_through_another_api_process_is_not_handed_out(member, pairs, other_process) -> None:
    from backend.services.pair_leases import pair_leases

    for free in pairs:  # whichever pair is the one left free, it is the one asked
        pair_leases.clear()
        assert other_process([pair for pair in pairs if pair != free]) == [True] * (len(pairs) - 1)
        assert asked(member) == free
    assert other_process([asked(member)]) == [False], "the other process sees this process's lease too"


def test_members_asking_at_the_same_instant_never_get_one_pair() -> None:
    from backend.services.pair_leases import PairLeases

    leases, start, won = PairLeases(), threading.Barrier(20), []

    def member(user_id: int) -> None:
        start.wait()
        if leases.claim((1, 2, 3), user_id):
            won.append(user_id)

    threads = [threading.Thread(target=member, args=(user_id,)) for user_id in range(1, 21)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert len(won) == 1
    assert leases.claim((1, 2, 3), won[0]), "the holder keeps their own pair"
    leases.release((1, 2, 3))
    assert leases.claim((1, 2, 3), 21 if won[0] != 21 else 1)


def test_leases_hold_within_the_process_while_redis_is_away(member, admin, pairs, broker_down) -> None:
    first, second = asked(member), asked(admin)
    assert first != second
    assert (
        admin.client.post(
            "/api/v1/labels", json={"snapshot_id": second[1], "clip_id": second[2], "verdict": "is"}
        ).status_code
        == 201
    )


def test_an_answered_pair_stays_held_for_whoever_looked_before_the_answer(
    member, pairs, other_process
) -> None:
    """Another member's next-pair query may have read the candidates just before this answer was committed:
    the lease, not the answer, must keep them from claiming the pair (and answering it second, 409)."""
    pair = asked(member)
    body = {"snapshot_id": pair[1], "clip_id": pair[2], "verdict": "is"}
    assert member.client.post("/api/v1/labels", json=body).status_code == 201
    assert other_process([pair]) == [False]
