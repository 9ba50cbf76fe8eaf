"""What the simulated rig peers share: a UDP socket bound on loopback served by one thread."""
from __future__ import annotations

import select
import socket
import threading


class UdpPeer:
    """Base of the loopback peers. Subclasses implement ``_run`` (the thread's loop, which must
    return soon after ``self._stop`` is set) and may extend ``_on_close`` (called after the thread
    stopped, before the socket closes)."""

    thread_name = 'sim-udp-peer'

    def _open(self, host: str, port: int, send_buffer: int | None = None) -> None:
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        if send_buffer:
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, send_buffer)
        self._sock.bind((host, port))
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=self.thread_name, daemon=True)

    def _start(self) -> None:
        self._thread.start()

    @property
    def address(self) -> tuple[str, int]:
        return self._sock.getsockname()[:2]

    @property
    def port(self) -> int:
        return self.address[1]

    def _wait_readable(self, timeout_s: float) -> bool | None:
        """True when a datagram is waiting, False on timeout, None once the socket is closed."""
        try:
            ready, _, _ = select.select([self._sock], [], [], timeout_s)
        except (OSError, ValueError):
            return None
        return bool(ready)

    def _recv(self, size: int):
        """(data, address) of one datagram, or None if the socket failed."""
        try:
            return self._sock.recvfrom(size)
        except OSError:
            return None

    def _run(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _on_close(self) -> None:
        """Hook: release what the subclass holds (the thread has stopped)."""

    def close(self, timeout_s: float = 2.0) -> None:
        if self._stop.is_set():
            return
        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout_s)
        self._on_close()
        self._sock.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()
