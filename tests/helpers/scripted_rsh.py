"""A scripted linuxcncrsh on loopback: plays the server's side of the text protocol so that the
host's session and machine code meet the replies real linuxcncrsh gives now and then (another
session's words, a NAK under concurrent sessions) on demand, without a simulator.

    server = ScriptedRsh(lambda line, connection: "HELLO ACK EMCNETSVR 1.1" if ... else None)
    RshSession.open("127.0.0.1", server.port, "pw")

``answer(line, connection)`` gets each request line and the 0-based number of the connection it
came on, and returns the reply line, or None for the standard reply (``Session.reply``).  Each
connection keeps linuxcncrsh's own flags: echo starts on (every line after a good hello is copied
back before its reply), verbose off (a ``set`` goes through without an ACK); ``set echo|verbose``
answered by the standard reply changes them, one answered by ``answer`` (a NAK) does not.
``received`` holds (connection, line) in arrival order.
"""

from __future__ import annotations

import contextlib
import socket
import threading
from collections.abc import Callable, Iterator

Answer = Callable[[str, int], "str | None"]


class Session:
    """One connection's flags, as linuxcncrsh keeps them per session."""

    def __init__(self) -> None:
        self.linked, self.echo, self.verbose = False, True, False

    def reply(self, line: str) -> str | None:
        """What linuxcncrsh answers to a request that goes through (None: no line), updating
        the flags: ``hello`` -> ``HELLO ACK EMCNETSVR 1.1``; ``set`` before it -> ``SET NAK``;
        ``set <name> ...`` -> ``SET <NAME> ACK`` when verbose, else nothing; ``get
        echo|verbose`` -> the flag; any other ``get <name>`` -> ``<NAME> OK``."""
        words = line.split()
        if len(words) < 2:  # quit, shutdown
            return line.upper()
        if words[0] == "hello":
            self.linked = True
            return "HELLO ACK EMCNETSVR 1.1"
        if words[0] == "set" and not self.linked:
            return "SET NAK"
        if words[0] == "set":
            if words[1] in ("echo", "verbose") and len(words) > 2:
                setattr(self, words[1], words[2] == "on")
            return f"SET {words[1].upper()} ACK" if self.verbose else None
        if words[1] in ("echo", "verbose"):
            return f"{words[1].upper()} {'ON' if getattr(self, words[1]) else 'OFF'}"
        return f"{words[1].upper()} OK"


def in_turn(prefix: str, *replies: str) -> Answer:
    """An ``answer`` giving the lines that start with ``prefix`` the ``replies`` in turn (then
    the standard reply), every other line the standard reply."""
    queue: Iterator[str] = iter(replies)
    return lambda line, _: next(queue, None) if line.startswith(prefix) else None


class ScriptedRsh:
    """A loopback server answering every connection by ``answer`` (see the module docstring)."""

    def __init__(self, answer: Answer) -> None:
        self.answer = answer
        self.received: list[tuple[int, str]] = []
        self._listener = socket.create_server(("127.0.0.1", 0))
        self.port: int = self._listener.getsockname()[1]
        threading.Thread(target=self._accept, daemon=True).start()

    def lines(self, prefix: str) -> list[str]:
        """The received lines that start with ``prefix``."""
        return [line for _, line in self.received if line.startswith(prefix)]

    def close(self) -> None:
        self._listener.close()

    def _accept(self) -> None:
        connection = 0
        with contextlib.suppress(OSError):  # the listener closed
            while True:
                conn, _ = self._listener.accept()
                threading.Thread(target=self._talk, args=(conn, connection), daemon=True).start()
                connection += 1

    def _talk(self, conn: socket.socket, connection: int) -> None:
        session = Session()
        with conn, conn.makefile("rwb") as stream, contextlib.suppress(ConnectionError):
            for raw in stream:  # until the client closes (a reset when it closes unread)
                line = raw.decode().strip()
                self.received.append((connection, line))
                copy = line if session.echo and session.linked else None
                reply = self.answer(line, connection)
                if reply is None:
                    reply = session.reply(line)
                elif reply.startswith("HELLO ACK"):
                    session.linked = True
                stream.write(b"".join(text.encode() + b"\r\n" for text in (copy, reply) if text is not None))
                stream.flush()


def printing_machine(server: ScriptedRsh):  # type: ignore[no-untyped-def]
    """A ``LinuxCNCMachine`` talking to ``server`` on one session, in ``printing`` (as a
    program's run or a stop finds it)."""
    from hardware.linuxcnc.machine import LinuxCNCMachine
    from hardware.linuxcnc.rsh import RshSession

    machine = LinuxCNCMachine(f"linuxcnc://127.0.0.1:{server.port}?joints=3", connect_pw="pw",
                              enable_pw="pw", timeout_s=5.0)
    machine.machine_state.link = RshSession.open("127.0.0.1", server.port, "pw")
    machine.machine_state.current = "printing"
    return machine
