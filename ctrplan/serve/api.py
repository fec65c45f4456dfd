"""The JSON API of `ctrplan serve` (docs/cli.md): requests in, (HTTP status, JSON document) out.

- ``POST /api/plan`` ``{"target_mm": [x, y, z], "tolerance_mm": t}`` -> one entry of ``plan --roadmap
  --targets --json`` (``solved``, ``query_time_s``, ``path``, ``validated``, ``message``, ...) plus
  ``structures`` (clearance to each structure along the path, nearest first);
- ``POST /api/structures/NAME/move`` ``{"translation_mm": [dx, dy, dz]}`` -> the structure's shift and
  the roadmap repair's record; later plans respect its new place;
- ``GET /api/scene`` -> structures (name, margin, shift), base pose (4x4, mm), target, roadmap summary
  (or null).

A bad request gets a 4xx status and ``{"error": "<one line>"}``; nothing a request carries ends the
server. A plan or a move also reaches the page (``on_change``).
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable
from typing import Any

from ctrplan.base.errors import InputError
from ctrplan.serve.session import PlanSession

#: Largest request body (bytes).
MAX_BODY = 65536
_MOVE = re.compile(r"^/api/structures/([^/]+)/move$")


class ApiError(Exception):
    """A request refused: HTTP ``status`` and one line."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status


def handle(session: PlanSession, method: str, path: str, body: bytes,
           on_change: Callable[[str, Any], None] = lambda kind, value: None) -> tuple[int, dict]:
    """Answer one request; ``on_change("plan", answer)`` / ``("move", record)`` after a change."""
    try:
        path = path.split("?", 1)[0].rstrip("/") or "/"
        if path == "/api/scene":
            _method(method, "GET", path)
            return 200, session.describe()
        if path == "/api/plan":
            _method(method, "POST", path)
            doc = _json(body)
            centre = _vector(doc, "target_mm")
            tol = _number(doc, "tolerance_mm", default=float(session.target.tolerance_mm))
            if tol <= 0:
                raise ApiError(400, f"tolerance_mm: must be > 0 (mm), got {tol:g}")
            answer = session.plan(centre, tol)
            on_change("plan", answer)
            return 200, answer.to_json()
        move = _MOVE.match(path)
        if move:
            _method(method, "POST", path)
            record = session.move(_unquote(move.group(1)), _vector(_json(body), "translation_mm"))
            on_change("move", record)
            return 200, record
        raise ApiError(404, f"no such endpoint: {path} (see docs/cli.md, `ctrplan serve`)")
    except ApiError as exc:
        return exc.status, {"error": str(exc)}
    except InputError as exc:
        status = 404 if str(exc).startswith("no structure named") else 400
        return status, {"error": str(exc)}


def _method(method: str, allowed: str, path: str) -> None:
    if method != allowed:
        raise ApiError(405, f"{path} takes {allowed}, not {method}")


def _json(body: bytes) -> dict:
    if len(body) > MAX_BODY:
        raise ApiError(413, f"request body of {len(body)} bytes; at most {MAX_BODY}")
    try:
        doc = json.loads(body.decode("utf-8") or "null")
    except (UnicodeDecodeError, ValueError) as exc:
        raise ApiError(400, f"body is not JSON ({exc})") from None
    if not isinstance(doc, dict):
        raise ApiError(400, "body must be a JSON object")
    return doc


def _number(doc: dict, key: str, default: float | None = None) -> float:
    value = doc.get(key, default)
    if value is None:
        raise ApiError(400, f"{key}: missing")
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ApiError(400, f"{key}: must be a finite number (mm), got {json.dumps(value)}")
    return float(value)


def _vector(doc: dict, key: str) -> list[float]:
    value = doc.get(key)
    if value is None:
        raise ApiError(400, f"{key}: missing (three numbers, mm, scene frame)")
    if not isinstance(value, list) or len(value) != 3:
        raise ApiError(400, f"{key}: must be three numbers (mm, scene frame), got {json.dumps(value)}")
    return [_number({key: v}, key) for v in value]


def _unquote(name: str) -> str:
    from urllib.parse import unquote

    return unquote(name)
