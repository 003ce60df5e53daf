"""One linuxcncrsh session: a TCP text conversation with LinuxCNC's remote shell.

    session = RshSession.open("127.0.0.1", 5007, connect_pw="EMC", timeout_s=5.0)
    session.enable("EMCTOO")                 # this session may now command the machine
    session.set("mode", "mdi")               # "SET MODE ACK" or RshRejected
    session.get("joint_pos")                 # "0.000000 5.000000 ..." (the value part)

Protocol facts this module relies on (linuxcncrsh of LinuxCNC 2.9, measured):

* ``hello <pw> <client> <version>`` answers ``HELLO ACK <server> <version>`` / ``HELLO NAK``;
  echo starts ON (``set echo off`` is answered by its own echo), verbose starts OFF (with
  ``set verbose on`` every ``set`` answers ``SET <NAME> ACK`` or ``SET <NAME> NAK``);
  ``get echo`` / ``get verbose`` answer ``ECHO ON|OFF`` / ``VERBOSE ON|OFF``.
* ``get <name>`` answers ``<NAME> <value>``; replies end in ``\\r\\n`` (ACKs in ``\\n\\r``).
* A ``set`` that reaches the controller is answered only after the controller received
  it (about 100-200 ms); ``get`` answers at once, also while another session waits.
* Only the session that enabled itself last may ``set`` (a later ``set enable`` on another
  session silently takes control): the emergency-stop session enables itself right
  before it stops.
* ``get`` now and then answers ``GET NAK`` (status read raced an update), and sessions
  that talk at the same moment sometimes receive each other's replies or a NAK (its parser's
  ``strtok`` state is shared by every session's thread): ``get`` and ``hello`` retry, echo
  and verbose are read back until they hold, ``set`` skips lines that are not its own
  ACK/NAK.  Keep concurrent sessions rare (the machine polls on one session; the stop
  session speaks only to stop).
* ``get error`` returns the oldest unread controller error once (then ``OK``).
* ``set timeout`` (``set_timeout`` in the manual): any value > 0 makes every wait fail
  at once in this build, so waits are bounded by the socket timeout instead.

Every request holds the session lock, so pause/resume from another thread interleave
with a polling loop but never inside one request.  Errors: ``LinkError`` when the socket
fails or times out (the session is then dead), ``RshRejected`` for a NAK.
"""

from __future__ import annotations

import socket
import threading
import time

from ..errors import FirmwareError, LinkError

__all__ = ["RshRejected", "RshSession"]


class RshRejected(FirmwareError):
    """linuxcncrsh answered NAK (``reason`` is the controller's error text, if any)."""


# the values that list every joint or axis (at least three words on any config): a shorter
# one was read with another session's argument (``get`` asks again)
VALUE_WORDS = {"joint_homed": 3, "joint_pos": 3, "abs_act_pos": 3, "rel_cmd_pos": 3}


class RshSession:
    """A line-based linuxcncrsh conversation (see the module docstring)."""

    def __init__(self, sock: socket.socket, timeout_s: float) -> None:
        self._sock = sock
        self._buffer = b""
        self._lock = threading.RLock()
        self.timeout_s = timeout_s
        self.healthy = True
        self.server = ""

    @classmethod
    def open(cls, host: str, port: int, connect_pw: str, *, timeout_s: float = 5.0,
             client: str = "conforma") -> RshSession:
        """Connect, say hello, turn echo off and verbose on."""
        try:
            sock = socket.create_connection((host, port), timeout=timeout_s)
        except OSError as exc:
            raise LinkError(f"cannot reach linuxcncrsh at {host}:{port}: {exc}", field="port",
                            value=f"{host}:{port}") from exc
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        session = cls(sock, timeout_s)
        try:
            session.server = session._hello(connect_pw, client)
            session._switch("echo", "off")
            session._switch("verbose", "on")
        except Exception:
            session.close()
            raise
        return session

    def _hello(self, connect_pw: str, client: str, retries: int = 5, refusals: int = 3) -> str:
        """Say hello; returns what follows ``HELLO ACK`` (the server's name and version).

        linuxcncrsh (LinuxCNC 2.9) parses every session's line with ``strtok``, whose state
        all its session threads share: while another session talks, a hello can be parsed
        with that session's words and answered ``HELLO NAK`` although the password is right,
        and one session's reply can reach another (both seen under load).  Hello changes
        nothing, so it is said again: ``refusals`` NAKs in a row are a wrong password, any
        other reply is retried up to ``retries`` times."""
        naks = others = 0
        while True:
            reply = self.request(f"hello {connect_pw} {client} 1.0")
            head = reply.upper()
            if head.startswith("HELLO ACK"):
                return reply[len("HELLO ACK"):].strip()
            if head.startswith("HELLO NAK"):
                naks += 1
                if naks >= refusals:
                    raise LinkError(f"linuxcncrsh refused the connect password ({naks} hellos in a "
                                    "row answered HELLO NAK)", field="connect_pw")
            else:
                naks, others = 0, others + 1
                if others > retries:
                    raise LinkError(f"linuxcncrsh answered hello with {reply[:60]!r} {others} times",
                                    field="port")
            time.sleep(0.002 * (naks + others))

    def _switch(self, flag: str, value: str, attempts: int = 5) -> None:
        """``set <flag> <value>`` for one of this session's own flags (echo, verbose), read back
        with ``get <flag>`` and said again until it holds.

        Under load the shared ``strtok`` can parse the ``set`` with another session's words: it
        is answered NAK and the flag keeps its old value.  Echo left on puts a copy of every
        request before its reply; verbose left off leaves every ``set`` without an ACK; either
        would make the next ``set`` read the wrong line.  The flags belong to this session
        alone, so saying them again changes nothing else.  The read-back's answer is the first
        line that is neither a copy of a request nor a ``SET`` reply; anything but
        ``<FLAG> <VALUE>`` (a ``GET NAK``, another session's words) means try again."""
        requests = (f"set {flag} {value}", f"get {flag}")
        for attempt in range(attempts):
            with self._lock:
                for line in requests:
                    self.send_only(line)
                while True:
                    reply = self._next_line(requests[1], None)
                    if reply not in requests and not reply.upper().startswith("SET "):
                        break
            if reply.upper().split() == [flag.upper(), value.upper()]:
                return
            time.sleep(0.002 * (attempt + 1))
        raise LinkError(f"linuxcncrsh did not keep 'set {flag} {value}' in {attempts} tries (last "
                        f"read back {reply[:60]!r})", field="port")

    # ------------------------------------------------------------------ transport
    def _read_line(self, timeout_s: float) -> str:
        self._sock.settimeout(timeout_s)
        while True:
            cut = min((i for i in (self._buffer.find(b"\n"), self._buffer.find(b"\r")) if i >= 0),
                      default=-1)
            if cut >= 0:
                line, self._buffer = self._buffer[:cut], self._buffer[cut + 1:]
                text = line.decode("utf-8", "replace").strip()
                if text:
                    return text
                continue
            chunk = self._sock.recv(4096)
            if not chunk:
                raise ConnectionError("linuxcncrsh closed the connection")
            self._buffer += chunk

    def request(self, line: str, timeout_s: float | None = None) -> str:
        """Send one request line and return the first non-empty reply line."""
        if "\n" in line or "\r" in line:
            raise ValueError("one request per line")
        with self._lock:
            if not self.healthy:
                raise LinkError("the linuxcncrsh session is closed", field="port")
            try:
                self._sock.sendall(line.encode("utf-8") + b"\r\n")
                return self._read_line(self.timeout_s if timeout_s is None else timeout_s)
            except (OSError, ConnectionError) as exc:
                self.healthy = False
                self._close_socket()
                raise LinkError(f"linuxcncrsh session lost during {line.split(' ')[0]!r} "
                                f"{line.split(' ')[1] if ' ' in line else ''}: {exc}",
                                field="port") from exc

    def send_only(self, line: str) -> None:
        """Send a request that gets no reply (``shutdown``)."""
        with self._lock:
            try:
                self._sock.sendall(line.encode("utf-8") + b"\r\n")
            except OSError as exc:
                self.healthy = False
                raise LinkError(f"linuxcncrsh session lost: {exc}", field="port") from exc

    # ------------------------------------------------------------------ commands
    def get(self, name: str, *args: str, retries: int = 5, words: int = 0) -> str:
        """``get name args`` -> the value part of ``NAME value``.  A ``GET NAK``, a reply
        to another request or a value of fewer words than ``words`` or ``VALUE_WORDS`` says is retried
        (``get`` has no side effects): linuxcncrsh answers NAK when its status read races an
        update, and while sessions talk concurrently it now and then hands one session's reply
        to another or reads an argument from the other session's line (``get joint_pos``
        answered for one joint, ``JOINT_POS <n> <value>``; measured in 2.9)."""
        words = max(words, VALUE_WORDS.get(name.lower(), 0) if not args else 0)
        for attempt in range(retries + 1):
            reply = self.request(" ".join(["get", name, *args]))
            head, _, value = reply.partition(" ")
            if head.upper() == name.upper() and len(value.split()) >= words:
                return value.strip()
            time.sleep(0.002 * (attempt + 1))
        raise RshRejected(f"linuxcncrsh answered 'get {name}' with {reply[:60]!r} {retries + 1} "
                          "times", command=f"get {name}")

    def set(self, name: str, *args: str, timeout_s: float | None = None) -> None:
        """``set name args``; ``RshRejected`` (with the controller's error) on NAK.  Lines
        that are not this command's ACK/NAK (another session's misrouted reply) are
        skipped."""
        command = " ".join(["set", name, *args])
        expected = f"SET {name.upper()} "
        with self._lock:
            reply = self.request(command, timeout_s).upper()
            while not reply.startswith(expected):
                reply = self._next_line(command, timeout_s).upper()
        if reply.endswith(" ACK"):
            return
        reason = self.pop_error()
        raise RshRejected(f"LinuxCNC rejected {command!r}" + (f": {reason}" if reason else ""),
                          command=command)

    def set_mode(self, mode: str, timeout_s: float = 3.0) -> None:
        """``set mode <mode>``, then wait until ``get mode`` reports it: the controller takes the
        mode asynchronously and refuses it while it still finishes something (right after
        homing an MDI command may otherwise meet "Must be in MDI mode").  Sent again every
        0.5 s; after ``timeout_s`` the next command meets the controller's own refusal.
        Nothing is sent when the controller already reports ``mode`` (as LinuxCNC's own GUIs
        switch modes): linuxcncrsh answers a ``set`` only after polling the controller every
        0.1 s, so a redundant switch before each MDI command cost 0.1 s per command."""
        if self.get("mode").upper() == mode.upper():
            return
        deadline = time.monotonic() + timeout_s
        while True:
            self.set("mode", mode)
            resend = time.monotonic() + 0.5
            while time.monotonic() < min(resend, deadline):
                if self.get("mode").upper() == mode.upper():
                    return
                time.sleep(0.01)
            if time.monotonic() >= deadline:
                return

    def _next_line(self, command: str, timeout_s: float | None) -> str:
        try:
            return self._read_line(self.timeout_s if timeout_s is None else timeout_s)
        except (OSError, ConnectionError) as exc:
            self.healthy = False
            self._close_socket()
            raise LinkError(f"linuxcncrsh session lost waiting for {command!r}: {exc}",
                            field="port") from exc

    def enable(self, enable_pw: str, timeout_s: float | None = None) -> None:
        """Take control of the machine for this session (the reply awaited ``timeout_s``,
        default the session's own)."""
        try:
            self.set("enable", enable_pw, timeout_s=timeout_s)
        except RshRejected as exc:
            raise LinkError("linuxcncrsh refused the enable password", field="enable_pw") from exc

    def pop_error(self) -> str | None:
        """The controller's oldest unread error text, or None."""
        text = self.get("error")
        return None if text.upper() == "OK" else text

    def close(self) -> None:
        """Say quit (best effort) and close the socket."""
        with self._lock:
            if self.healthy:
                try:
                    self._sock.sendall(b"quit\r\n")
                except OSError:
                    pass
            self.healthy = False
            self._close_socket()

    def _close_socket(self) -> None:
        try:
            self._sock.close()
        except OSError:
            pass

    def sever(self) -> None:
        """Cut the TCP connection abruptly (tests: a lost link)."""
        try:
            self._sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
