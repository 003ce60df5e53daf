"""The mock printer as a network serial bridge in a process of its own (tests only).

``python -m tests.helpers.mock_tcp_printer --port P --status-port S [--dialect marlin] [--time-scale 1]``

A real controller outlives its host: when the server dies, a printer behind a TCP-serial
bridge (ser2net, ESP3D) keeps its position, its line number and whatever it had buffered,
and runs it to the end.  This process is that printer: the firmware of one ``MockWorld``
behind ``socket://127.0.0.1:P``.  When the client goes away the mock port is closed like
an unplugged cable (Marlin keeps running and keeps its line number; grbl resets), and the
next client talks to the same firmware.  Every connection to the status port gets one JSON
line: ``{"executed": n, "commands": [...], "position": [x, y, z], "clients": k}``.
"""

from __future__ import annotations

import argparse
import json
import socket
import threading

import serial

from hardware.mock import MockWorld, register_world

WORLD = "tcp-printer"


def _pump_replies(port: serial.SerialBase, client: socket.socket) -> None:
    """Firmware -> client until the port is closed or the client is gone."""
    while True:
        try:
            data = port.read(port.in_waiting or 1)
        except (serial.SerialException, OSError, TypeError, AttributeError):
            return
        if data:
            try:
                client.sendall(data)
            except OSError:
                return


def _serve_client(client: socket.socket, url: str) -> None:
    port = serial.serial_for_url(url, timeout=0.01)
    replies = threading.Thread(target=_pump_replies, args=(port, client), daemon=True)
    replies.start()
    try:
        while True:
            data = client.recv(4096)
            if not data:
                break
            port.write(data)
    except (OSError, serial.SerialException):
        pass
    finally:
        port.close()  # the cable is pulled: the firmware keeps what it had
        replies.join(1.0)
        client.close()


def _serve_status(listener: socket.socket, world: MockWorld, clients: list[int]) -> None:
    while True:
        conn, _ = listener.accept()
        with world.lock:
            body = {"executed": world.executed_count, "commands": list(world.transcript.commands),
                    "position": list(world.position), "clients": clients[0]}
        with conn:
            conn.sendall((json.dumps(body) + "\n").encode())


def status(port: int, timeout: float = 5.0) -> dict:
    """Read the printer's status (for tests)."""
    with socket.create_connection(("127.0.0.1", port), timeout=timeout) as conn:
        data = b""
        while not data.endswith(b"\n"):
            chunk = conn.recv(65536)
            if not chunk:
                break
            data += chunk
    return json.loads(data)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--status-port", type=int, required=True)
    parser.add_argument("--dialect", default="marlin", choices=["marlin", "grbl"])
    parser.add_argument("--time-scale", type=float, default=1.0)
    args = parser.parse_args(argv)
    world = register_world(WORLD, MockWorld(dialect=args.dialect, time_scale=args.time_scale))
    clients = [0]
    status_listener = socket.create_server(("127.0.0.1", args.status_port))
    threading.Thread(target=_serve_status, args=(status_listener, world, clients), daemon=True).start()
    listener = socket.create_server(("127.0.0.1", args.port))
    print(f"mock {args.dialect} printer on socket://127.0.0.1:{args.port}", flush=True)
    while True:  # one client at a time, like a serial line
        client, _ = listener.accept()
        clients[0] += 1
        _serve_client(client, f"mock://{WORLD}")


if __name__ == "__main__":
    main()
