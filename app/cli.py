"""``conforma`` command line: serve, worker, migrate, keys, demo."""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from pathlib import Path

from app.config import ROLES, Settings, SettingsError, load_settings
from app.ownership import MachineOwnerLock


def _settings(args: argparse.Namespace, **extra: object) -> Settings:
    overrides = {"data_dir": getattr(args, "data_dir", None), **extra}
    return load_settings(**overrides)


def cmd_serve(args: argparse.Namespace) -> int:
    import uvicorn

    from app.auth import KeyRing
    from app.db import make_engine, migrate
    from app.main import create_app

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
    from app.db import migrate
    from app.jobs.runtime import QUEUES, Runtime

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
    from app.db import migrate

    settings = _settings(args)
    migrate(settings, args.revision)
    print(f"migrated {settings.resolved_database_url.split('@')[-1]} to {args.revision}")
    return 0


def cmd_keys(args: argparse.Namespace) -> int:
    from sqlmodel import Session, select

    from app.auth import KeyRing
    from app.db import make_engine, migrate
    from app.models import ApiKey

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
            for row in session.exec(select(ApiKey).order_by(ApiKey.created_at)).all():
                state = "revoked" if row.revoked_at else "active"
                print(f"{row.id}\t{row.role}\t{row.prefix}...\t{state}\t{row.name}")
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from app.demo import run_demo

    run_demo(_settings(args), args)
    return 0


START_HERE = """start here:
  conforma demo     seed S1's closed loop on the mock printer: probes, compensates and prints
                    nine traces and prints the before/after table (about 10 s)
  conforma serve    then the service: the pages at http://127.0.0.1:8000/ (the first start
                    prints an operator API key), the API at /api/v1, its docs at /docs
  conforma keys create --role operator    another key (viewer, operator or admin)
"""


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

    demo = sub.add_parser("demo", help="seed S1's experiment on the mock printer: closed loop + Table 1")
    data_dir(demo)
    from app.demo import add_arguments

    add_arguments(demo)
    demo.set_defaults(func=cmd_demo)

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
