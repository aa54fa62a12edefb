"""Domain errors raised by services (usable from workers too); the app turns them into `{"detail": ...}`."""


class ApiError(Exception):
    status_code = 400
    headers: dict[str, str] | None = None  # e.g. Retry-After

    def __init__(self, detail: str) -> None:
        super().__init__(detail)
        self.detail = detail


class NotFound(ApiError):
    status_code = 404

    def __init__(self, what: str, item_id: int | str) -> None:
        super().__init__(f"{what} {item_id} not found")


class Forbidden(ApiError):
    status_code = 403


class Conflict(ApiError):
    status_code = 409


class Invalid(ApiError):
    status_code = 422


class Unavailable(ApiError):
    status_code = 503


class QuotaExceeded(ApiError):
    status_code = 429

    def __init__(self, detail: str, retry_after_s: int) -> None:
        super().__init__(detail)
        self.headers = {"Retry-After": str(retry_after_s)}
