"""``fleethealth serve`` in a process of its own, as deployed, for tests and benchmarks that
need real sockets, real processes or a kill."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[2]


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@contextmanager
def serving(url: str, data_dir: Path, *, start_timeout: float = 60.0, port: int | None = None,
            ) -> Iterator[tuple[subprocess.Popen[bytes], str]]:
    """``fleethealth serve`` on the migrated database ``url`` (no demo, its job runner on),
    until /health answers; yields the process and its base URL, and stops it after (if it
    still runs). ``port``: the port to serve on (None: a free one)."""
    port = port or free_port()
    env = {**os.environ, "FLEETHEALTH_DATABASE_URL": url, "FLEETHEALTH_DATA_DIR": str(data_dir),
           "FLEETHEALTH_LOG_LEVEL": "WARNING", "FLEETHEALTH_LOG_JSON": "false",
           "OMP_NUM_THREADS": "1"}
    command = [sys.executable, "-c", "from app.cli import main; main()", "serve", "--no-demo",
               "--skip-migrate", "--host", "127.0.0.1", "--port", str(port)]
    server = subprocess.Popen(command, env=env, cwd=ROOT, stdout=subprocess.DEVNULL)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + start_timeout
        while True:
            try:
                if httpx.get(f"{base}/health", timeout=1).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            if server.poll() is not None:
                raise RuntimeError("fleethealth serve exited")
            if time.monotonic() > deadline:
                raise RuntimeError("fleethealth serve did not start")
            time.sleep(0.05)
        yield server, base
    finally:
        if server.poll() is None:
            server.terminate()
            server.wait(timeout=30)
