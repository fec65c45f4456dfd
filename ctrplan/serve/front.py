"""The one address of `ctrplan serve`: a small asyncio server that answers ``/api/...`` itself (JSON,
`ctrplan.serve.api`) and passes every other connection -- the page, its files and its websocket -- byte
for byte to the viser server on a private port.

Why a front: viser serves its page through the websockets library, which takes only GET requests and
has no hook for routes of one's own; a proxy at the byte level keeps one address for the page and the
API without touching viser. A request's head is read (up to `MAX_HEAD` bytes); ``/api/`` requests are
answered in a worker thread (planning takes milliseconds to seconds: the loop keeps serving the page)
and the connection closed; anything else is connected to viser with the bytes read so far, then both
directions are copied until either side closes.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import sys
import threading
import traceback
from collections.abc import Callable

#: Largest request head (bytes).
MAX_HEAD = 65536
#: Seconds a client has to send its request head.
HEAD_TIMEOUT_S = 30.0

Handler = Callable[[str, str, bytes], tuple[int, dict]]
_REASONS = {200: "OK", 400: "Bad Request", 404: "Not Found", 405: "Method Not Allowed",
            413: "Payload Too Large", 500: "Internal Server Error"}


class FrontServer:
    """Serves ``handler`` (method, path, body) -> (status, document) under ``/api/`` on
    ``host:port`` and proxies everything else to ``127.0.0.1:upstream_port``, in a thread of its own;
    `start` returns once the port is bound (`port` then says which), `stop` closes it."""

    def __init__(self, host: str, port: int, upstream_port: int, handler: Handler):
        self.host, self.port, self.upstream_port, self.handler = host, port, upstream_port, handler
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: asyncio.Server | None = None
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None

    def start(self) -> None:
        ready = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(ready,), name="ctrplan-serve", daemon=True)
        self._thread.start()
        ready.wait()
        if self._error is not None:
            raise self._error

    def _run(self, ready: threading.Event) -> None:
        self._loop = asyncio.new_event_loop()
        try:
            self._server = self._loop.run_until_complete(
                asyncio.start_server(self._client, self.host, self.port, reuse_address=True))
            self.port = self._server.sockets[0].getsockname()[1]
        except OSError as exc:
            self._error = exc
            ready.set()
            return
        ready.set()
        with contextlib.suppress(asyncio.CancelledError):
            self._loop.run_until_complete(self._server.serve_forever())
        self._loop.close()

    def stop(self) -> None:
        if self._loop is not None and self._server is not None:
            self._loop.call_soon_threadsafe(self._server.close)
            for task in asyncio.all_tasks(self._loop) if not self._loop.is_closed() else ():
                self._loop.call_soon_threadsafe(task.cancel)
        if self._thread is not None:
            self._thread.join(timeout=5.0)

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), HEAD_TIMEOUT_S)
        except (asyncio.IncompleteReadError, asyncio.LimitOverrunError, asyncio.TimeoutError, OSError):
            writer.close()
            return
        parts = head.split(b"\r\n", 1)[0].decode("latin-1").split(" ")
        method, path = (parts[0], parts[1]) if len(parts) >= 2 else ("", "")
        try:
            if path.startswith("/api/") or path == "/api":
                await self._api(method, path, head, reader, writer)
            else:
                await self._proxy(head, reader, writer)
        except (ConnectionError, OSError, asyncio.IncompleteReadError):
            pass
        finally:
            with contextlib.suppress(Exception):
                writer.close()

    async def _api(self, method: str, path: str, head: bytes, reader: asyncio.StreamReader,
                   writer: asyncio.StreamWriter) -> None:
        length = 0
        for line in head.split(b"\r\n")[1:]:
            name, _, value = line.partition(b":")
            if name.strip().lower() == b"content-length":
                try:
                    length = int(value.strip())
                except ValueError:
                    length = -1
        if length < 0 or length > 1 << 20:
            status, doc = (400, {"error": "bad Content-Length"}) if length < 0 else \
                (413, {"error": f"request body of {length} bytes is too large"})
        else:
            body = await reader.readexactly(length) if length else b""
            loop = asyncio.get_running_loop()
            status, doc = await loop.run_in_executor(None, self._answer, method, path, body)
        data = json.dumps(doc).encode()
        writer.write(f"HTTP/1.1 {status} {_REASONS.get(status, 'Error')}\r\n"
                     f"Content-Type: application/json\r\nContent-Length: {len(data)}\r\n"
                     f"Connection: close\r\n\r\n".encode() + data)
        await writer.drain()

    def _answer(self, method: str, path: str, body: bytes) -> tuple[int, dict]:
        """The handler's answer; an error it did not expect is a 500 with one line (and its traceback
        on stderr), never the end of the server."""
        try:
            return self.handler(method, path, body)
        except Exception as exc:  # noqa: BLE001 - the server must outlive any one request
            traceback.print_exc(file=sys.stderr)
            return 500, {"error": f"internal error: {type(exc).__name__}: {exc}"}

    async def _proxy(self, head: bytes, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        up_reader, up_writer = await asyncio.open_connection("127.0.0.1", self.upstream_port)
        up_writer.write(head)
        try:
            await asyncio.gather(_copy(reader, up_writer), _copy(up_reader, writer))
        finally:
            up_writer.close()


async def _copy(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    """Copy until end of stream, then close the other side's writing half."""
    try:
        while data := await reader.read(65536):
            writer.write(data)
            await writer.drain()
    except (ConnectionError, OSError):
        pass
    finally:
        with contextlib.suppress(Exception):
            writer.close()
