"""``conforma`` command line: serve, worker, migrate, keys, demo, mock-printer."""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from pathlib import Path

from sqlmodel import col

from app.platform.config import ROLES, Settings, SettingsError, load_settings
from app.platform.ownership import MachineOwnerLock
from hardware.dialects import DEFAULT_DIALECT, DIALECTS


def _settings(args: argparse.Namespace, **extra: object) -> Settings:
    return load_settings(None, data_dir=getattr(args, "data_dir", None), **extra)


def cmd_serve(args: argparse.Namespace) -> int:
    import uvicorn

    from app.main import create_app
    from app.platform.auth import KeyRing
    from app.platform.db import make_engine, migrate

    settings = _settings(args, host=args.host, port=args.port, viewer_port=args.viewer_port,
                         viewer=False if args.no_viewer else None)
    migrate(settings)
    owner = MachineOwnerLock(settings.data_dir)
    if not owner.acquire():
        print(f"another Conforma server (pid {owner.holder_pid()}) already runs on {settings.data_dir}: "
              "one process owns a data directory's machines; stop it or use --data-dir", file=sys.stderr)
        return 1
    engine = make_engine(settings)
    keyring = KeyRing(engine, settings.static_keys())
    new_key = None
    if not keyring.has_any():
        _record, new_key = keyring.create("operator", "generated on first start")
    engine.dispose()
    print(f"Conforma {settings.data_dir} -> http://{settings.host}:{settings.port}/  (API docs: /docs)", flush=True)
    if new_key:
        print(f"Operator API key (shown once, store it): {new_key}", flush=True)
    uvicorn.run(create_app(settings), host=settings.host, port=settings.port, log_level=settings.log_level)
    return 0


def cmd_worker(args: argparse.Namespace) -> int:
    from app.platform.db import migrate
    from app.runtime.engine import QUEUES, Runtime

    settings = _settings(args)
    migrate(settings)
    runtime = Runtime(settings)
    queues = tuple(args.queue) if args.queue else ("default",)
    unknown = [q for q in queues if q not in QUEUES]
    if unknown:
        print(f"unknown queue(s) {unknown}; known: {QUEUES}", file=sys.stderr)
        return 2
    runtime.start_workers(queues)
    print(f"worker {runtime.worker_id} on queues {', '.join(queues)}", flush=True)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    stop.wait()
    runtime.stop()
    return 0


def cmd_migrate(args: argparse.Namespace) -> int:
    from app.platform.db import migrate

    settings = _settings(args)
    migrate(settings, args.revision)
    print(f"migrated {settings.resolved_database_url.split('@')[-1]} to {args.revision}")
    return 0


def cmd_keys(args: argparse.Namespace) -> int:
    from sqlmodel import Session, select

    from app.platform.auth import KeyRing
    from app.platform.db import make_engine, migrate
    from app.platform.models import ApiKey

    settings = _settings(args)
    migrate(settings)
    engine = make_engine(settings)
    keyring = KeyRing(engine, {})
    if args.keys_command == "create":
        record, key = keyring.create(args.role, args.name)
        print(f"{record.id} {record.role} {key}")
    elif args.keys_command == "revoke":
        if not keyring.revoke(args.key_id):
            print(f"no active key {args.key_id!r}", file=sys.stderr)
            return 1
        print(f"revoked {args.key_id}")
    else:
        with Session(engine) as session:
            for row in session.exec(select(ApiKey).order_by(col(ApiKey.created_at))).all():
                state = "revoked" if row.revoked_at else "active"
                print(f"{row.id}\t{row.role}\t{row.prefix}...\t{state}\t{row.name}")
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from app.demo import run_demo

    run_demo(_settings(args), args)
    return 0


def _is_loopback(host: str) -> bool:
    """Whether ``host`` names only this machine (127.0.0.0/8, ::1, localhost)."""
    import ipaddress

    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def cmd_mock_printer(args: argparse.Namespace) -> int:
    """The mock firmware on a pseudo-terminal and/or a TCP port until interrupted."""
    from urllib.parse import urlencode

    from hardware.errors import InvalidConfig
    from hardware.mock import parse_mock_options, unregister_world
    from hardware.mock.expose import PtyBridge, TcpMockServer

    if not args.pty and args.tcp is None:
        print("mock-printer: give --pty and/or --tcp PORT", file=sys.stderr)
        return 2
    pairs = [("dialect", args.dialect), ("time_scale", str(args.time_scale))]
    for item in args.set or []:
        key, sep, value = item.partition("=")
        if not sep:
            print(f"mock-printer: --set needs KEY=VALUE, got {item!r}", file=sys.stderr)
            return 2
        pairs.append((key.strip(), value.strip()))
    query = urlencode(pairs)
    try:
        parse_mock_options(query)
    except InvalidConfig as exc:
        print(f"mock-printer: {exc.message}", file=sys.stderr)
        return 2
    url = f"mock://{args.name}?{query}"
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    exposed: list = []
    try:
        if args.pty:
            exposed.append(PtyBridge(url, baudrate=args.baud))
            print(f"pty {exposed[-1].path}", flush=True)
        if args.tcp is not None:
            if not _is_loopback(args.host):
                print(f"mock-printer: warning: listening on {args.host}, not loopback: anyone who reaches this "
                      "address can drive the mock firmware (it has no authentication)", file=sys.stderr, flush=True)
            exposed.append(TcpMockServer(url, port=args.tcp, host=args.host, baudrate=args.baud))
            host, port = exposed[-1].address
            print(f"tcp {host}:{port}", flush=True)
        stop.wait(args.seconds)
    finally:
        for item in exposed:
            item.close()
    from hardware.mock import get_world

    digest = get_world(args.name).transcript.digest()
    print(f"executed {digest.count} commands sha256 {digest.sha256}", flush=True)
    unregister_world(args.name)
    return 0


START_HERE = """start here:
  conforma demo     the published closed loop on the mock printer: probes, compensates and prints
                    nine traces and prints the before/after table (about 10 s)
  conforma serve    then the service: the pages at http://127.0.0.1:8000/ (the first start
                    prints an operator API key), the API at /api/v1, its docs at /docs
  conforma keys create --role operator    another key (viewer, operator or admin)
"""


def _demo_arguments(parser: argparse.ArgumentParser) -> None:
    """``conforma demo``'s options (here, so that building the parser imports no job runtime:
    ``mock-printer``, ``keys`` and ``migrate`` start without it)."""
    parser.add_argument("--traces", default="1-9", help="trace numbers, e.g. 1-9 or 1,4,7")
    parser.add_argument("--seed", type=int, default=11, help="seed of the machining error field")
    parser.add_argument("--amplitude-mm", type=float, default=0.15, help="machining error amplitude")
    parser.add_argument("--dz-mm", type=float, default=0.03, help="placement offset in z")
    parser.add_argument("--noise-um", type=float, default=1.0, help="probe noise (1 sigma)")
    parser.add_argument("--planner", choices=("adaptive", "uniform", "deviation"), default="deviation")
    parser.add_argument("--grid-mm", type=float, default=0.3, help="tessellation of the part meshes")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="conforma", description=__doc__, epilog=START_HERE,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)

    def data_dir(p: argparse.ArgumentParser, nested: bool = False) -> None:
        # a nested command (keys list) takes it too, without overriding the parent's value
        p.add_argument("--data-dir", type=Path, default=argparse.SUPPRESS if nested else None,
                       help="default: CONFORMA_DATA_DIR or ./data")

    serve = sub.add_parser("serve", help="API + embedded worker + viewer")
    data_dir(serve)
    serve.add_argument("--host", default=None)
    serve.add_argument("--port", type=int, default=None)
    serve.add_argument("--viewer-port", type=int, default=None)
    serve.add_argument("--no-viewer", action="store_true")
    serve.set_defaults(func=cmd_serve)

    worker = sub.add_parser("worker", help="a worker process (more workers = more throughput)")
    data_dir(worker)
    worker.add_argument("--queue", action="append",
                        help="default: the compute queue; 'machine' only on the host that owns the ports")
    worker.set_defaults(func=cmd_worker)

    mig = sub.add_parser("migrate", help="apply database migrations")
    data_dir(mig)
    mig.add_argument("--revision", default="head")
    mig.set_defaults(func=cmd_migrate)

    demo = sub.add_parser("demo", help="the published experiment on the mock printer: closed loop + its width table")
    data_dir(demo)
    _demo_arguments(demo)
    demo.set_defaults(func=cmd_demo)

    mock = sub.add_parser("mock-printer", help="the mock firmware on a pty or TCP port for any host")
    mock.add_argument("--pty", action="store_true", help="open a pseudo-terminal and print its path")
    mock.add_argument("--tcp", type=int, default=None, metavar="PORT", help="listen on PORT (0: any)")
    mock.add_argument("--host", default="127.0.0.1", help="TCP address (default loopback only)")
    mock.add_argument("--dialect", choices=tuple(DIALECTS), default=DEFAULT_DIALECT)
    mock.add_argument("--time-scale", type=float, default=0.0,
                      help="1 = real-time firmware timing, 0 = as fast as possible")
    mock.add_argument("--baud", type=int, default=115200)
    mock.add_argument("--name", default="mock-printer", help="mock world name")
    mock.add_argument("--set", action="append", metavar="KEY=VALUE",
                      help="mock world or fault option, e.g. checksum_rate=0.01, seed=3, "
                           "probe_noise_mm=0.01, homing=1 (see hardware/mock/world.py)")
    mock.add_argument("--seconds", type=float, default=None, help="stop after this many seconds")
    mock.set_defaults(func=cmd_mock_printer)

    keys = sub.add_parser("keys", help="manage API keys")
    data_dir(keys)
    keys_sub = keys.add_subparsers(dest="keys_command", required=True)
    create = keys_sub.add_parser("create", help="a new key, printed once")
    create.add_argument("--role", choices=ROLES, required=True)
    create.add_argument("--name", default="")
    revoke = keys_sub.add_parser("revoke", help="revoke a key by its id")
    revoke.add_argument("key_id")
    listing = keys_sub.add_parser("list", help="the stored keys (ids, roles, names; never the keys)")
    for nested in (create, revoke, listing):
        data_dir(nested, nested=True)
    keys.set_defaults(func=cmd_keys)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    for chatty in ("huey", "alembic"):  # start-up banners, not events
        logging.getLogger(chatty).setLevel(logging.WARNING)
    try:
        return int(args.func(args) or 0)
    except SettingsError as exc:
        print(f"configuration error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
