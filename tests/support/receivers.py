"""Local receivers for notification tests, on real sockets of 127.0.0.1: an HTTP server that
records webhook requests (answering with the status codes it is told), and a small SMTP server
written on asyncio (the standard library's smtpd is deprecated) that records messages and
checks AUTH PLAIN credentials."""

from __future__ import annotations

import asyncio
import base64
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from email import message_from_bytes
from email.message import Message
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer


@dataclass
class Received:
    path: str
    headers: dict[str, str]
    body: bytes


@dataclass
class WebhookReceiver:
    """Answers each POST with the next of ``codes`` (the last one repeats)."""

    codes: list[int] = field(default_factory=lambda: [200])
    requests: list[Received] = field(default_factory=list)
    url: str = ""


@contextmanager
def webhook_receiver(codes: list[int] | None = None) -> Iterator[WebhookReceiver]:
    receiver = WebhookReceiver(codes=list(codes or [200]))

    class Handler(BaseHTTPRequestHandler):
        def do_POST(self) -> None:  # noqa: N802 - the http.server spelling
            length = int(self.headers.get("Content-Length", "0"))
            receiver.requests.append(
                Received(self.path, dict(self.headers.items()), self.rfile.read(length))
            )
            n = len(receiver.requests) - 1
            code = receiver.codes[min(n, len(receiver.codes) - 1)]
            self.send_response(code)
            self.send_header("Content-Length", "0")
            self.end_headers()

        def log_message(self, format: str, *args: object) -> None:  # noqa: A002
            return None

    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    receiver.url = f"http://127.0.0.1:{server.server_address[1]}/hooks/fleet"
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield receiver
    finally:
        server.shutdown()
        server.server_close()
        thread.join(timeout=5)


@dataclass
class Mail:
    mail_from: str
    rcpt_to: list[str]
    message: Message
    login: str | None


@dataclass
class SmtpReceiver:
    port: int = 0
    messages: list[Mail] = field(default_factory=list)
    credentials: tuple[str, str] | None = None


class _Session:
    def __init__(self, receiver: SmtpReceiver, reader: asyncio.StreamReader,
                 writer: asyncio.StreamWriter) -> None:
        self.receiver, self.reader, self.writer = receiver, reader, writer
        self.mail_from = ""
        self.rcpt: list[str] = []
        self.login: str | None = None

    async def reply(self, line: str) -> None:
        self.writer.write(line.encode() + b"\r\n")
        await self.writer.drain()

    async def run(self) -> None:
        await self.reply("220 localhost fleethealth test SMTP")
        while line := await self.reader.readline():
            command = line.decode().rstrip("\r\n")
            verb = command.split(" ", 1)[0].upper()
            arg = command[len(verb):].strip()
            if verb in ("EHLO", "HELO"):
                if self.receiver.credentials is not None:
                    await self.reply("250-localhost")
                    await self.reply("250 AUTH PLAIN")
                else:
                    await self.reply("250 localhost")
            elif verb == "AUTH":
                await self.auth(arg)
            elif verb == "MAIL":
                if self.receiver.credentials is not None and self.login is None:
                    await self.reply("530 authentication required")
                    continue
                self.mail_from, self.rcpt = arg.split(":", 1)[1].strip(" <>"), []
                await self.reply("250 OK")
            elif verb == "RCPT":
                self.rcpt.append(arg.split(":", 1)[1].strip(" <>"))
                await self.reply("250 OK")
            elif verb == "DATA":
                await self.reply("354 end with <CRLF>.<CRLF>")
                data = bytearray()
                while (chunk := await self.reader.readline()) not in (b".\r\n", b""):
                    data += chunk[1:] if chunk.startswith(b"..") else chunk
                self.receiver.messages.append(
                    Mail(self.mail_from, self.rcpt, message_from_bytes(bytes(data)), self.login)
                )
                await self.reply("250 OK queued")
            elif verb == "RSET" or verb == "NOOP":
                await self.reply("250 OK")
            elif verb == "QUIT":
                await self.reply("221 bye")
                break
            else:
                await self.reply("502 command not implemented")
        self.writer.close()

    async def auth(self, arg: str) -> None:
        mechanism, _, initial = arg.partition(" ")
        if mechanism.upper() != "PLAIN":
            await self.reply("504 unrecognised authentication type")
            return
        if not initial:
            await self.reply("334 ")
            initial = (await self.reader.readline()).decode().strip()
        _zid, user, password = base64.b64decode(initial).decode().split("\0")
        if (user, password) == self.receiver.credentials:
            self.login = user
            await self.reply("235 authentication successful")
        else:
            await self.reply("535 authentication credentials invalid")


@contextmanager
def smtp_receiver(credentials: tuple[str, str] | None = None) -> Iterator[SmtpReceiver]:
    receiver = SmtpReceiver(credentials=credentials)
    loop = asyncio.new_event_loop()
    started = threading.Event()
    holder: dict[str, asyncio.AbstractServer] = {}

    async def serve() -> None:
        server = await asyncio.start_server(
            lambda r, w: _Session(receiver, r, w).run(), "127.0.0.1", 0
        )
        receiver.port = server.sockets[0].getsockname()[1]
        holder["server"] = server
        started.set()

    def run() -> None:
        asyncio.set_event_loop(loop)
        loop.run_until_complete(serve())
        loop.run_forever()

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    started.wait(5)
    try:
        yield receiver
    finally:
        async def stop() -> None:
            holder["server"].close()
            await holder["server"].wait_closed()

        asyncio.run_coroutine_threadsafe(stop(), loop).result(5)
        loop.call_soon_threadsafe(loop.stop)
        thread.join(timeout=5)
        loop.close()
