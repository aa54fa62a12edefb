"""Accounts: sign-in (cookie + CSRF, bearer token), sign-out, members and roles."""

from apitest_helpers import PASSWORD
from fastapi.testclient import TestClient


def test_login_sets_an_httponly_samesite_session_cookie(wired_app, admin) -> None:
    client = TestClient(wired_app)
    response = client.post("/api/v1/auth/login", json={"username": "alice", "password": PASSWORD})
    assert response.status_code == 200
    cookies = response.headers.get_list("set-cookie")
    session_cookie = next(c for c in cookies if c.startswith("varbot_session="))
    assert "HttpOnly" in session_cookie and "SameSite=lax" in session_cookie
    csrf_cookie = next(c for c in cookies if c.startswith("varbot_csrf="))
    assert "HttpOnly" not in csrf_cookie
    assert response.json()["user"]["role"] == "admin"
    assert client.get("/api/v1/auth/me").json()["username"] == "alice"


def test_wrong_password_and_unknown_user_are_refused_alike(wired_app, admin) -> None:
    client = TestClient(wired_app)
    wrong = client.post("/api/v1/auth/login", json={"username": "alice", "password": "nope nope"})
    unknown = client.post("/api/v1/auth/login", json={"username": "zed", "password": PASSWORD})
    assert wrong.status_code == unknown.status_code == 401
    assert wrong.json() == unknown.json()


def test_requests_without_a_session_get_401(wired_app) -> None:
    response = TestClient(wired_app).get("/api/v1/robots")
    assert response.status_code == 401
    assert "sign in" in response.json()["detail"]


def test_cookie_writes_need_the_csrf_token(admin) -> None:
    del admin.client.headers["X-CSRF-Token"]
    refused = admin.client.post("/api/v1/robots", json={"name": "arm", "kind": "kuka-sim"})
    assert refused.status_code == 403 and "CSRF" in refused.json()["detail"]
    forged = admin.client.post(
        "/api/v1/robots", json={"name": "arm", "kind": "kuka-sim"}, headers={"X-CSRF-Token": "guess"}
    )
    assert forged.status_code == 403
    assert admin.client.get("/api/v1/robots").status_code == 200  # reads need no token
    accepted = admin.client.post(
        "/api/v1/robots", json={"name": "arm", "kind": "kuka-sim"}, headers={"X-CSRF-Token": admin.csrf}
    )
    assert accepted.status_code == 201


def test_bearer_tokens_for_scripts_need_no_csrf(wired_app, admin) -> None:
    client = TestClient(wired_app)
    token = client.post("/api/v1/auth/token", data={"username": "alice", "password": PASSWORD})
    assert token.status_code == 200 and token.json()["token_type"] == "bearer"
    headers = {"Authorization": f"Bearer {token.json()['access_token']}"}
    assert (
        client.post("/api/v1/robots", json={"name": "arm", "kind": "kuka-sim"}, headers=headers).status_code
        == 201
    )
    # A bearer token is not a cookie: the same string sent as the cookie is refused.
    client.cookies.set("varbot_session", token.json()["access_token"])
    assert client.get("/api/v1/robots").status_code == 401


def test_logout_ends_the_session(admin) -> None:
    assert admin.client.post("/api/v1/auth/logout").status_code == 204
    admin.client.cookies.clear()
    assert admin.client.get("/api/v1/auth/me").status_code == 401


def test_a_stolen_cookie_stops_working_after_logout(wired_app, admin) -> None:
    stolen = admin.client.cookies.get("varbot_session")
    admin.client.post("/api/v1/auth/logout")
    thief = TestClient(wired_app, cookies={"varbot_session": stolen})
    assert thief.get("/api/v1/auth/me").status_code == 401


def test_admin_adds_a_member_who_can_sign_in(wired_app, admin) -> None:
    created = admin.client.post(
        "/api/v1/members", json={"username": "carol", "display_name": "Carol", "password": "long enough pw"}
    )
    assert created.status_code == 201 and created.json()["role"] == "member"
    login = TestClient(wired_app).post(
        "/api/v1/auth/login", json={"username": "carol", "password": "long enough pw"}
    )
    assert login.status_code == 200
    assert {m["username"] for m in admin.client.get("/api/v1/members").json()} == {"alice", "carol"}


def test_usernames_are_unique(admin, member) -> None:
    again = admin.client.post(
        "/api/v1/members", json={"username": "bob", "display_name": "B", "password": "x" * 10}
    )
    assert again.status_code == 409


def test_members_cannot_manage_members(member) -> None:
    response = member.client.post(
        "/api/v1/members", json={"username": "eve", "display_name": "E", "password": "x" * 10}
    )
    assert response.status_code == 403


def test_admin_changes_roles_but_never_removes_the_last_admin(admin, member) -> None:
    promoted = admin.client.patch(f"/api/v1/members/{member.user_id}", json={"role": "admin"})
    assert promoted.json()["role"] == "admin"
    assert admin.client.patch(f"/api/v1/members/{member.user_id}", json={"role": "member"}).status_code == 200
    last = admin.client.patch(f"/api/v1/members/{admin.user_id}", json={"role": "member"})
    assert last.status_code == 409 and "at least one active admin" in last.json()["detail"]


def test_deactivated_members_are_signed_out(admin, member) -> None:
    admin.client.patch(f"/api/v1/members/{member.user_id}", json={"is_active": False})
    assert member.client.get("/api/v1/auth/me").status_code == 401


def test_changing_my_password_needs_the_current_one(wired_app, member) -> None:
    refused = member.client.patch(
        "/api/v1/auth/me", json={"current_password": "wrong", "new_password": "new password!"}
    )
    assert refused.status_code == 403
    changed = member.client.patch(
        "/api/v1/auth/me", json={"current_password": PASSWORD, "new_password": "new password!"}
    )
    assert changed.status_code == 200
    login = TestClient(wired_app).post(
        "/api/v1/auth/login", json={"username": "bob", "password": "new password!"}
    )
    assert login.status_code == 200


def test_household_is_visible_to_members_and_renamed_by_admins(admin, member) -> None:
    assert member.client.get("/api/v1/household").json()["name"] == "home"
    assert member.client.patch("/api/v1/household", json={"name": "ours"}).status_code == 403
    assert admin.client.patch("/api/v1/household", json={"name": "ours"}).json()["name"] == "ours"


def test_members_of_another_household_are_invisible(admin, stranger) -> None:
    assert {m["username"] for m in stranger.client.get("/api/v1/members").json()} == {"mallory"}
    assert (
        stranger.client.patch(f"/api/v1/members/{admin.user_id}", json={"role": "member"}).status_code == 404
    )


# --- sessions: listed, ended by the member, ended together when a password or role changes ---------------


def _bearer(wired_app, username: str, password: str = PASSWORD) -> dict[str, str]:  # type: ignore[no-untyped-def]
    token = TestClient(wired_app).post(
        "/api/v1/auth/token", data={"username": username, "password": password}
    )
    assert token.status_code == 200, token.text
    return {"Authorization": f"Bearer {token.json()['access_token']}"}


def _other_browser(wired_app, username: str) -> TestClient:  # type: ignore[no-untyped-def]
    browser = TestClient(wired_app)
    assert (
        browser.post("/api/v1/auth/login", json={"username": username, "password": PASSWORD}).status_code
        == 200
    )
    return browser


def test_a_new_password_signs_out_every_other_session_but_the_one_that_changed_it(wired_app, member) -> None:
    script = _bearer(wired_app, "bob")
    laptop = _other_browser(wired_app, "bob")
    changed = member.client.patch(
        "/api/v1/auth/me", json={"current_password": PASSWORD, "new_password": "a brand new password"}
    )
    assert changed.status_code == 200
    assert TestClient(wired_app).get("/api/v1/auth/me", headers=script).status_code == 401
    assert laptop.get("/api/v1/auth/me").status_code == 401
    assert member.client.get("/api/v1/auth/me").status_code == 200
    assert member.client.patch("/api/v1/auth/me", json={"display_name": "Bobby"}).status_code == 200


def test_a_wrong_current_password_changes_nothing_and_ends_no_session(wired_app, member) -> None:
    script = _bearer(wired_app, "bob")
    refused = member.client.patch(
        "/api/v1/auth/me", json={"current_password": "not it", "new_password": "a brand new password"}
    )
    assert refused.status_code == 403
    assert TestClient(wired_app).get("/api/v1/auth/me", headers=script).status_code == 200


def test_members_list_their_own_sessions_and_see_which_is_this_one(wired_app, admin, member) -> None:
    _bearer(wired_app, "bob")
    listed = member.client.get("/api/v1/auth/sessions")
    assert listed.status_code == 200
    sessions = listed.json()
    assert [s["kind"] for s in sessions] == ["cookie", "bearer"]
    assert [s["current"] for s in sessions] == [True, False]
    assert sessions[0]["user_agent"] == "testclient" and sessions[0]["client_address"] == "testclient"
    assert "token_hash" not in sessions[0] and "csrf_token" not in sessions[0]
    assert len(admin.client.get("/api/v1/auth/sessions").json()) == 1  # only one's own


def test_a_member_ends_one_of_their_sessions_but_not_someone_elses(wired_app, admin, member) -> None:
    script = _bearer(wired_app, "bob")
    bearer_id = member.client.get("/api/v1/auth/sessions").json()[1]["id"]
    alices = admin.client.get("/api/v1/auth/sessions").json()[0]["id"]
    assert member.client.delete(f"/api/v1/auth/sessions/{alices}").status_code == 404
    assert admin.client.get("/api/v1/auth/me").status_code == 200
    assert member.client.delete(f"/api/v1/auth/sessions/{bearer_id}").status_code == 204
    assert TestClient(wired_app).get("/api/v1/auth/me", headers=script).status_code == 401
    assert member.client.get("/api/v1/auth/me").status_code == 200


def test_signing_out_everywhere_else_keeps_this_session(wired_app, member) -> None:
    script = _bearer(wired_app, "bob")
    laptop = _other_browser(wired_app, "bob")
    assert member.client.delete("/api/v1/auth/sessions").status_code == 204
    assert TestClient(wired_app).get("/api/v1/auth/me", headers=script).status_code == 401
    assert laptop.get("/api/v1/auth/me").status_code == 401
    assert [s["current"] for s in member.client.get("/api/v1/auth/sessions").json()] == [True]


def test_a_new_role_signs_the_member_out_everywhere(wired_app, admin, member) -> None:
    script = _bearer(wired_app, "bob")
    assert admin.client.patch(f"/api/v1/members/{member.user_id}", json={"role": "admin"}).status_code == 200
    assert member.client.get("/api/v1/auth/me").status_code == 401
    assert TestClient(wired_app).get("/api/v1/auth/me", headers=script).status_code == 401
    assert admin.client.get("/api/v1/auth/me").status_code == 200


def test_an_admin_changing_their_own_role_stays_signed_in_here_only(wired_app, admin, member) -> None:
    admin.client.patch(f"/api/v1/members/{member.user_id}", json={"role": "admin"})
    alices_script = _bearer(wired_app, "alice")
    assert admin.client.patch(f"/api/v1/members/{admin.user_id}", json={"role": "member"}).status_code == 200
    assert admin.client.get("/api/v1/auth/me").json()["role"] == "member"
    assert TestClient(wired_app).get("/api/v1/auth/me", headers=alices_script).status_code == 401


def test_an_admin_resetting_a_password_signs_the_member_out_everywhere(wired_app, admin, member) -> None:
    script = _bearer(wired_app, "bob")
    reset = admin.client.patch(f"/api/v1/members/{member.user_id}", json={"password": "reset by alice!"})
    assert reset.status_code == 200
    assert member.client.get("/api/v1/auth/me").status_code == 401
    assert TestClient(wired_app).get("/api/v1/auth/me", headers=script).status_code == 401


# --- cookies outside development ----------------------------------------------------------------------------


def test_session_cookies_are_secure_in_production(wired_app, admin, monkeypatch) -> None:
    from conftest import clear_backend_caches

    monkeypatch.setenv("VARBOT_ENVIRONMENT", "production")
    clear_backend_caches()
    try:
        client = TestClient(wired_app, base_url="https://testserver")
        response = client.post("/api/v1/auth/login", json={"username": "alice", "password": PASSWORD})
        assert response.status_code == 200
        cookies = response.headers.get_list("set-cookie")
        assert len(cookies) == 2 and all("Secure" in cookie for cookie in cookies), cookies
        assert client.get("/api/v1/auth/me").status_code == 200
    finally:
        monkeypatch.undo()
        clear_backend_caches()


def test_session_cookies_are_not_secure_on_the_plain_http_test_server(admin, wired_app) -> None:
    response = TestClient(wired_app).post(
        "/api/v1/auth/login", json={"username": "alice", "password": PASSWORD}
    )
    assert not any("Secure" in cookie for cookie in response.headers.get_list("set-cookie"))
