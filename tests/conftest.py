"""Shared fixtures: every test app gets its own data directory and static keys."""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import scipy.linalg  # noqa: F401  (loads scipy's own OpenBLAS before the limit below)
from threadpoolctl import threadpool_limits

# Tests and benchmarks call the core directly: run it as a job process does, with
# CONFORMA_BLAS_THREADS's default of one BLAS thread (set once per process, never in the core).
# threadpoolctl limits the BLAS libraries loaded when it is called: numpy's and scipy's are
# two (scipy.linalg loads its own), so scipy.linalg is imported first (a job process has it
# loaded by its imports before its limit is set).
threadpool_limits(limits=1)

KEYS = {"viewer": "viewer-key-123", "operator": "operator-key-123", "admin": "admin-key-123"}
# Tests must not inherit a developer's configuration; CONFORMA_TEST_* select the real
# hardware the contract suite runs against (tests/hardware/test_contract.py) and stay.
for _name in [n for n in os.environ if n.startswith("CONFORMA_") and not n.startswith("CONFORMA_TEST_")]:
    os.environ.pop(_name)


def auth(role: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {KEYS[role]}"}


@pytest.fixture(scope="session")
def migrated_database(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A SQLite database migrated to head once per test process (the real migrations, on a
    fresh file).  Each test's data directory starts from a copy: migrating a fresh file costs
    0.15-0.2 s of every test app's start, ~1,000 times a run; the app's start-up still runs
    ``migrate``, which finds the copy at head."""
    import sqlite3

    from app.platform.config import load_settings
    from app.platform.db import migrate

    data_dir = tmp_path_factory.mktemp("migrated") / "data"
    migrate(load_settings({}, data_dir=data_dir, api_keys=f"{KEYS['admin']}:admin", viewer=False))
    database = data_dir / "conforma.db"
    with sqlite3.connect(database) as connection:  # everything in the main file: it is copied alone
        connection.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    return database


@pytest.fixture
def settings_factory(tmp_path: Path, migrated_database: Path):  # type: ignore[no-untyped-def]
    import shutil

    from app.platform.config import load_settings

    def make(**overrides: object):  # type: ignore[no-untyped-def]
        values: dict[str, object] = {
            "data_dir": tmp_path / "data",
            "api_keys": ",".join(f"{k}:{r}" for r, k in KEYS.items()),
            "viewer": False,
            "lease_s": 5.0,
            "reaper_interval_s": 0.2,
            "job_plugins": "tests.jobs.sample_kinds",
            # Most test apps never run a compute job: their compute processes start at the
            # first one instead of with the app (the warm-up is tested on its own).
            "compute_warm_up": False,
        }
        values.update(overrides)
        settings = load_settings({}, **values)
        if settings.is_sqlite and not (settings.data_dir / "conforma.db").exists():
            settings.data_dir.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(migrated_database, settings.data_dir / "conforma.db")
        return settings

    return make


@pytest.fixture
def settings(settings_factory):  # type: ignore[no-untyped-def]
    return settings_factory()


@pytest.fixture
def client(settings) -> Iterator:  # type: ignore[no-untyped-def]
    from fastapi.testclient import TestClient

    from app.main import create_app

    with TestClient(create_app(settings), raise_server_exceptions=False) as test_client:
        yield test_client


# ---- running on both cores (pytest-xdist, `make test` runs `-n 4 --dist loadgroup`) -------
# Tests that share one real resource of the host run on ONE worker, one after another:
# the LinuxCNC simulator (one HAL / linuxcncrsh per host), the Redis database and the
# PostgreSQL databases of the scale-out tests (keys and databases deleted per fixture), and
# the browser tests (one served instance and one Chromium per session).
SHARED_RESOURCE_GROUPS = {
    "tests/hardware/linuxcnc/": "linuxcnc",
    "tests/jobs/test_scale_out.py": "redis-postgresql",
    "tests/e2e/browser/": "browser",
}
# Where each simulator runs in namespaces of its own (as root: hardware.linuxcnc.sim_namespace),
# these LinuxCNC modules (about half of the group's ~500 s, the five-axis one among them, so
# only this group switches config) are a second group with its own simulator on another worker
LINUXCNC_SECOND_GROUP = ("test_machine.py", "test_jetting_run.py", "test_scan_run.py", "test_outputs_off.py",
                         "test_three_axis.py", "test_five_axis.py")


def shared_resource_group(nodeid: str) -> str | None:
    """The ``SHARED_RESOURCE_GROUPS`` group of a test node id or path (relative to the
    repository root); ``linuxcnc-2`` for ``LINUXCNC_SECOND_GROUP`` where simulators run side by side."""
    for prefix, group in SHARED_RESOURCE_GROUPS.items():
        if nodeid.startswith(prefix):
            module = nodeid[len(prefix):].split("::")[0]
            if group == "linuxcnc" and module in LINUXCNC_SECOND_GROUP and _simulators_side_by_side():
                return "linuxcnc-2"
            return group
    return None


def _simulators_side_by_side() -> bool:
    from hardware.linuxcnc.sim_namespace import isolation_available

    return isolation_available()


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log):  # type: ignore[no-untyped-def]
    """``--dist loadgroup`` with the groups taken from the node ids' paths.

    pytest-xdist 3.8 schedules loadgroup by an ``@group`` suffix it writes into
    ``item._nodeid``; pytest 9.2 reads node ids from ``item._id``, so that suffix is lost and
    every test was scheduled on its own: the LinuxCNC modules ran on both workers (each
    waiting up to 86 s for the other's simulator behind the file lock), and both workers
    started a served instance and a Chromium.  Here one group is one work unit, on one
    worker; with xdist's default ``--loadscope-reorder`` the groups (the largest units)
    are handed out first, and the single tests balance the two workers after them."""
    if config.getvalue("dist") != "loadgroup":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class SharedResourceScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return shared_resource_group(nodeid) or nodeid

    return SharedResourceScheduling(config, log)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    root = Path(__file__).resolve().parent.parent
    linuxcnc: list[int] = []
    for k, item in enumerate(items):
        where = item.path.resolve().relative_to(root).as_posix()
        group = shared_resource_group(where)
        if group is not None:
            item.add_marker(pytest.mark.xdist_group(group))
            if group.startswith("linuxcnc"):
                linuxcnc.append(k)
    # the LinuxCNC tests of the five-axis simulator after all three-axis ones (a stable
    # sort): one simulator serves many modules, and the config then switches once
    ordered = sorted((items[k] for k in linuxcnc), key=lambda item: "lcnc_trt" in item.fixturenames)
    for k, item in zip(linuxcnc, ordered):
        items[k] = item


# ---- the run's own duration, printed last (CI's log shows it) -------------------------------
_RUN_STARTED = pytest.StashKey[float]()


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--durations-log", metavar="PATH", default=None,
                     help="append each test phase's worker, node id, phase, duration and outcome to PATH "
                          "(tab-separated, as the phases finish); `python -m tests.helpers.durations PATH` sums it")


_durations_log: str | None = None  # --durations-log's path


def pytest_configure(config: pytest.Config) -> None:
    global _durations_log
    config.stash[_RUN_STARTED] = time.monotonic()
    _durations_log = config.getoption("durations_log")


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    """``--durations-log``: one line per test phase, written by the controlling process (under
    xdist the report names its worker), so a run cut short still leaves what it measured."""
    path = _durations_log
    if path is None or os.environ.get("PYTEST_XDIST_WORKER"):
        return
    gateway = getattr(getattr(report, "node", None), "gateway", None)
    worker = gateway.id if gateway is not None else "main"
    with open(path, "a", encoding="utf-8") as log:
        log.write(f"{worker}\t{report.nodeid}\t{report.when}\t{report.duration:.3f}\t{report.outcome}\n")


def pytest_terminal_summary(terminalreporter, exitstatus: int, config: pytest.Config) -> None:  # type: ignore[no-untyped-def]
    """One line with the whole run's wall time (collection included), the number of xdist
    workers and the host's load at the end: a wall time says little without the load."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        return
    wall = time.monotonic() - config.stash[_RUN_STARTED]
    workers = getattr(config.option, "numprocesses", None) or 0
    load = os.getloadavg()[0]
    terminalreporter.write_line(f"suite wall time: {int(wall // 60)} min {wall % 60:04.1f} s ({wall:.1f} s), "
                                f"{workers or 'no'} xdist workers, load average {load:.1f} at the end")
