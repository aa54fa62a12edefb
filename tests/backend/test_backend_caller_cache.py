"""The sign-in lookup cache: busy clients skip the database, and no change of who may do what waits for it."""

import pytest
from sqlalchemy import delete, select

from backend import models
from backend.security import SignedInCache, signed_in_cache


@pytest.fixture
def short_lived_cache(monkeypatch: pytest.MonkeyPatch) -> SignedInCache:
    signed_in_cache.clear()
    monkeypatch.setattr(signed_in_cache, "ttl_s", 60.0)
    return signed_in_cache


def test_a_recently_seen_session_is_answered_from_the_cache_until_it_expires(
    short_lived_cache, member, db, monkeypatch
) -> None:
    assert member.client.get("/api/v1/auth/me").status_code == 200
    # Removed behind the API's back (as another process would): the cache still knows the session …
    db.execute(delete(models.AuthSession).where(models.AuthSession.user_id == member.user_id))
    db.commit()
    assert member.client.get("/api/v1/auth/me").status_code == 200
    # … only until its entry expires (here: at once).
    short_lived_cache.clear()
    monkeypatch.setattr(short_lived_cache, "ttl_s", 0.0)
    assert member.client.get("/api/v1/auth/me").status_code == 401


def test_signing_out_forgets_the_cached_session_at_once(short_lived_cache, wired_app, member) -> None:
    from fastapi.testclient import TestClient

    stolen = member.client.cookies.get("varbot_session")
    assert member.client.get("/api/v1/auth/me").status_code == 200
    assert member.client.post("/api/v1/auth/logout").status_code == 204
    thief = TestClient(wired_app, cookies={"varbot_session": stolen})
    assert thief.get("/api/v1/auth/me").status_code == 401


def test_a_demoted_admin_loses_admin_rights_at_once(short_lived_cache, admin, member) -> None:
    assert admin.client.patch(f"/api/v1/members/{member.user_id}", json={"role": "admin"}).status_code == 200
    rename = {"display_name": "Bob B."}
    assert admin.client.patch(f"/api/v1/members/{member.user_id}", json=rename).status_code == 200
    # Alice steps down herself: the session she did it from stays signed in (and cached), not as an admin.
    assert admin.client.patch(f"/api/v1/members/{admin.user_id}", json={"role": "member"}).status_code == 200
    assert admin.client.patch(f"/api/v1/members/{member.user_id}", json=rename).status_code == 403


def test_a_deactivated_member_is_refused_at_once(short_lived_cache, admin, member) -> None:
    assert member.client.get("/api/v1/auth/me").status_code == 200
    admin.client.patch(f"/api/v1/members/{member.user_id}", json={"is_active": False})
    assert member.client.get("/api/v1/auth/me").status_code == 401


def test_a_lookup_that_raced_with_a_sign_out_is_not_remembered() -> None:
    cache = SignedInCache(ttl_s=60.0)
    entry = type("Entry", (), {"user_id": 7, "auth_session_id": 3})()
    started = cache.generation
    cache.forget(auth_session_id=3)  # committed while the lookup was reading the old row
    cache.remember("hash", "bearer", entry, started)
    assert cache.get("hash", "bearer") is None
    cache.remember("hash", "bearer", entry, cache.generation)
    assert cache.get("hash", "bearer") is entry


def test_the_cache_stays_within_its_size() -> None:
    cache = SignedInCache(ttl_s=60.0, max_entries=3)
    for n in range(10):
        cache.remember(f"hash{n}", "bearer", object(), cache.generation)
    assert cache.get("hash9", "bearer") is not None and cache.get("hash0", "bearer") is None


def test_label_counts_follow_labels_answered_and_undone(admin, db) -> None:
    from apitest_helpers import make_robot, upload_clip, upload_snapshot

    snapshot = upload_snapshot(admin, make_robot(admin)).json()["id"]
    clip = upload_clip(admin, name="left").json()["id"]

    def counts() -> tuple[int, int]:
        db.expire_all()
        return (
            db.scalar(select(models.Snapshot.label_count).where(models.Snapshot.id == snapshot)),
            db.scalar(select(models.Clip.label_count).where(models.Clip.id == clip)),
        )

    assert counts() == (0, 0)
    created = admin.client.post(
        "/api/v1/labels", json={"snapshot_id": snapshot, "clip_id": clip, "verdict": "is"}
    )
    assert created.status_code == 201 and counts() == (1, 1)
    assert admin.client.put(f"/api/v1/labels/{created.json()['id']}", json={"verdict": "is_not"}).is_success
    assert counts() == (1, 1)
    assert admin.client.delete(f"/api/v1/labels/{created.json()['id']}").status_code == 204
    assert counts() == (0, 0)
