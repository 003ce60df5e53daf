"""The machine lease (``MachineManager.lease``) and the machine kinds taken from the registry."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from app.domain.errors import Conflict
from app.machines.live import MachineManager
from app.platform.problems import http_status
from app.runtime.machine_queue import WORKFLOW_KINDS, machine_slot
from app.runtime.registry import load_kinds, machine_kinds
from app.runtime.store import OPERATOR_RESUMED_KINDS

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def machines():
    manager = MachineManager(lambda _part_id: None)
    yield manager
    manager.close_all()


def test_lease_records_the_job_and_releases_after_success(machines):
    with machines.lease("m1", "job-a"):
        assert machines.running_job == {"m1": "job-a"}
    assert machines.running_job == {}


def test_lease_releases_after_an_exception(machines):
    with pytest.raises(RuntimeError, match="link dropped"), machines.lease("m1", "job-a"):
        assert machines.running_job["m1"] == "job-a"
        raise RuntimeError("link dropped")
    assert "m1" not in machines.running_job
    with machines.lease("m1", "job-b"):  # free again for the next job
        assert machines.running_job["m1"] == "job-b"


def test_lease_is_refused_while_another_job_holds_the_machine(machines):
    with machines.lease("m1", "job-a"):
        with pytest.raises(Conflict) as info, machines.lease("m1", "job-b"):
            pytest.fail("the second lease was granted")
        assert http_status(info.value)[0] == 409 and info.value.field == "params.machine_id"
        assert "job-a" in info.value.message
        assert machines.running_job == {"m1": "job-a"}  # the refusal leaves the holder alone
        with machines.lease("m2", "job-b"):  # another machine is independent
            assert machines.running_job == {"m1": "job-a", "m2": "job-b"}
    assert machines.running_job == {}


def test_lease_is_reentrant_for_the_same_job(machines):
    with machines.lease("m1", "job-a"):
        with machines.lease("m1", "job-a"):
            assert machines.running_job["m1"] == "job-a"
        assert machines.running_job["m1"] == "job-a"  # the inner exit keeps the outer lease
    assert machines.running_job == {}


def test_machine_kinds_come_from_the_registry_and_match_the_old_list():
    load_kinds()
    assert set(machine_kinds()) == {"print", "probe_run", "register", "calibrate_probe", "calibrate_nozzle", "scan_run",
                                     "calibrate_sensor",
                                     "jetting_run"}
    assert machine_slot("print", {"machine_id": "m1"}) == "m1"
    assert machine_slot("toolpath", {"machine_id": "m1"}) is None
    # the reaper's list (kept literal so that a process that loaded no kinds still never requeues
    # a machine job) agrees with the registry
    assert set(OPERATOR_RESUMED_KINDS) == set(machine_kinds()) | set(WORKFLOW_KINDS)


def test_no_kind_writes_running_job_directly():
    writes = [f"{path.relative_to(ROOT)}:{n}" for path in (ROOT / "app").rglob("*.py")
              if path != ROOT / "app" / "machines" / "live.py"
              for n, line in enumerate(path.read_text().splitlines(), 1)
              if re.search(r"running_job\s*\[[^\]]*\]\s*=|running_job\.(pop|clear|update|setdefault)\(", line)]
    assert writes == []
