"""The mock firmware on a real pseudo-terminal or TCP port, so that any host can talk to it.

    bridge = PtyBridge("mock://printrun?checksum_rate=0.01&seed=3")
    bridge.path          # "/dev/pts/7": open it with any serial host (Printrun, OctoPrint...)
    ...
    bridge.close()

    server = TcpMockServer("mock://bench?dialect=grbl", port=0)   # port 0: any free port
    server.address       # ("127.0.0.1", 40123); one client at a time, like a serial port

Bytes are copied both ways between the host's side and a ``mock://`` port of
``hardware.mock.protocol_mock``; the mock world (``get_world``) keeps the transcript of
what the firmware executed.  A new TCP client re-opens the mock port, which resets the
controller as opening a USB serial port resets an Arduino-based board.  TCP listens on the
loopback address unless told otherwise: the mock has no authentication.
"""

from __future__ import annotations

import os
import pty
import select
import socket
import threading
import tty
from collections.abc import Callable

import serial

from . import register_protocol_handler

register_protocol_handler()


def _pump_port_to(port: serial.SerialBase, send: Callable[[bytes], object], stop: threading.Event) -> None:
    """Copy the mock's replies to the host (``send(bytes)``) until ``stop`` or the port dies."""
    while not stop.is_set():
        try:
            data = port.read(port.in_waiting or 1)
        except (serial.SerialException, OSError, TypeError, AttributeError):
            return
        if data:
            try:
                send(data)
            except OSError:
                return


class PtyBridge:
    """A pseudo-terminal whose far end is the mock firmware at ``url`` (a ``mock://`` URL)."""

    def __init__(self, url: str, baudrate: int = 115200) -> None:
        self.url = url
        self.port = serial.serial_for_url(url, baudrate=baudrate, timeout=0.05)
        self._master, self._slave = pty.openpty()
        tty.setraw(self._slave)  # no echo, no CR/LF translation: a plain byte pipe
        self.path = os.ttyname(self._slave)
        self._stop = threading.Event()
        self._threads = [
            threading.Thread(target=self._host_to_mock, daemon=True, name="pty-to-mock"),
            threading.Thread(target=_pump_port_to, args=(self.port, self._to_host, self._stop),
                             daemon=True, name="mock-to-pty"),
        ]
        for thread in self._threads:
            thread.start()

    def _to_host(self, data: bytes) -> None:
        os.write(self._master, data)

    def _host_to_mock(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self._master], [], [], 0.05)
            if not ready:
                continue
            try:
                data = os.read(self._master, 4096)
            except OSError:  # nobody holds the slave side open: wait for the next host
                self._stop.wait(0.05)
                continue
            if data:
                try:
                    self.port.write(data)
                except serial.SerialException:
                    return

    def close(self) -> None:
        """Stop copying and close the pty and the mock port."""
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=1.0)
        self.port.close()
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self) -> PtyBridge:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class TcpMockServer:
    """The mock firmware at ``url`` behind a TCP port; one client at a time."""

    def __init__(self, url: str, port: int = 0, host: str = "127.0.0.1",
                 baudrate: int = 115200) -> None:
        self.url = url
        self.baudrate = baudrate
        self._listener = socket.create_server((host, port))
        self._listener.settimeout(0.1)
        self.address = self._listener.getsockname()[:2]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True, name="mock-tcp")
        self._thread.start()

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            with conn:
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)  # a line at a time
                self._session(conn)

    def _session(self, conn: socket.socket) -> None:
        port = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=0.05)
        done = threading.Event()
        reader = threading.Thread(target=_pump_port_to, args=(port, conn.sendall, done),
                                  daemon=True, name="mock-to-tcp")
        reader.start()
        conn.settimeout(0.1)
        try:
            while not self._stop.is_set():
                try:
                    data = conn.recv(4096)
                except TimeoutError:
                    continue
                except OSError:
                    break
                if not data:
                    break
                port.write(data)
        finally:
            done.set()
            reader.join(timeout=1.0)
            port.close()

    def close(self) -> None:
        """Stop accepting and end the current session."""
        self._stop.set()
        self._listener.close()
        self._thread.join(timeout=2.0)

    def __enter__(self) -> TcpMockServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
