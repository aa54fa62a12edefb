"""Serving bytes with HTTP range requests (what the browser's <audio> element asks for)."""

import re

from fastapi import Request, Response, status

_RANGE = re.compile(r"^bytes=(\d*)-(\d*)$")


def ranged_response(request: Request, data: bytes, media_type: str, etag: str) -> Response:
    size = len(data)
    headers = {"Accept-Ranges": "bytes", "ETag": f'"{etag}"', "Cache-Control": "private, max-age=3600"}
    if request.headers.get("if-none-match") == headers["ETag"]:
        return Response(status_code=status.HTTP_304_NOT_MODIFIED, headers=headers)
    spec = request.headers.get("range")
    if not spec:
        return Response(data, media_type=media_type, headers=headers)
    match = _RANGE.match(spec.strip())
    if match is None or match.groups() == ("", ""):
        return _unsatisfiable(size, headers)
    first, last = match.groups()
    if first == "":  # the last N bytes
        start, end = max(0, size - int(last)), size - 1
    else:
        start, end = int(first), min(int(last), size - 1) if last else size - 1
    if start >= size or start > end:
        return _unsatisfiable(size, headers)
    headers["Content-Range"] = f"bytes {start}-{end}/{size}"
    return Response(
        data[start : end + 1],
        status_code=status.HTTP_206_PARTIAL_CONTENT,
        media_type=media_type,
        headers=headers,
    )


def _unsatisfiable(size: int, headers: dict[str, str]) -> Response:
    headers = headers | {"Content-Range": f"bytes */{size}"}
    return Response(status_code=status.HTTP_416_RANGE_NOT_SATISFIABLE, headers=headers)
