"""Live machine connections of this process (the one that owns the serial ports).

A registered machine is a row; connecting builds a backend (:class:`hardware.backend.Machine`)
from it: :class:`hardware.linuxcnc.LinuxCNCMachine` for ``linuxcnc://`` ports, else the serial
:class:`hardware.machine.Machine`.  For ``mock://`` ports the mock firmware's world is built from the row's
``mock`` settings: the true part is the stored mesh of ``true_part_id`` with its rigid
placement, probe noise, timing and faults.  Hardware errors are translated into the
service's error family here, so routers and jobs only see :mod:`app.domain.errors`.
"""

from __future__ import annotations

import ipaddress
import os
import re
import socket
import stat
import threading
from collections.abc import Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import Any

from app.domain.errors import Conflict, ConformaError, InvalidInput
from app.platform.models import Machine as MachineRow
from hardware.backend import Machine
from hardware.errors import (
    CommandRejected,
    HardwareError,
    InvalidConfig,
    LinkError,
    MachineBusy,
    MachineStateError,
    ProbeFailed,
)
from hardware.machine import Machine as SerialMachine
from hardware.machine_types import MachineProfile
from hardware.mock import (
    FaultConfig,
    MockPad,
    MockSphere,
    MockTool,
    MockWorld,
    TruePlacement,
    register_world,
    unregister_world,
)
from hardware.port_url import PortUrl


class MachineUnavailable(ConformaError):
    """The port cannot be reached or the firmware does not answer (503)."""

    status = 503
    title = "Machine unavailable"


class MachineFault(ConformaError):
    """The firmware halted, raised an alarm, or answered nonsense (502); a command it
    refuses for what it says is an InvalidInput (422) naming it."""

    status = 502
    title = "Machine fault"


class ProbeMissed(InvalidInput):
    """The probe reached its lower limit without touching anything."""


def translate(exc: HardwareError) -> ConformaError:
    """The service error for a hardware error (message, field and value kept)."""
    field = getattr(exc, "field", None)
    value = getattr(exc, "value", None)
    kind: type[ConformaError]
    if isinstance(exc, (MachineBusy, MachineStateError)):
        kind = Conflict
    elif isinstance(exc, InvalidConfig):
        kind = InvalidInput
    elif isinstance(exc, ProbeFailed):
        kind = ProbeMissed
    elif isinstance(exc, LinkError):
        kind = MachineUnavailable
    elif isinstance(exc, CommandRejected):  # the command's fault: 422 naming it
        field, value = field or "command", value if value is not None else exc.command
        kind = InvalidInput
    else:  # FirmwareError, ProtocolError and anything else the firmware side raised
        kind = MachineFault
    return kind(str(exc), field=field, value=value)


@contextmanager
def hardware_errors() -> Iterator[None]:
    """Re-raise hardware errors as service errors."""
    try:
        yield
    except HardwareError as exc:
        raise translate(exc) from exc


def profile_of(row: MachineRow) -> MachineProfile:
    fields = {k: v for k, v in (row.profile or {}).items() if k in MachineProfile.__dataclass_fields__}
    with hardware_errors():
        return MachineProfile(**fields)


def port_url(row: MachineRow) -> str:
    """The URL to open: ``mock://`` ports get the machine's own world name."""
    parts = PortUrl.parse(row.port)
    if parts.is_mock:
        query = f"?{parts.query}" if parts.query else ""
        return f"mock://{row.id}{query}"
    return row.port


def _tcp_host(host: str, port: str) -> str:
    """The one name of a TCP host: ``loopback`` for any loopback address (``localhost``,
    127.0.0.1, ::1 reach the same controller), else the lowest address it resolves to."""
    try:
        infos = socket.getaddrinfo(host, None, type=socket.SOCK_STREAM)
    except (socket.gaierror, UnicodeError) as exc:
        raise InvalidInput(f"host {host!r} does not resolve: {exc}", field="port", value=port) from None
    addresses = sorted({ipaddress.ip_address(str(info[4][0]).split("%")[0]) for info in infos},
                       key=lambda a: (a.version, int(a)))
    if any(a.is_loopback for a in addresses):
        return "loopback"
    return str(addresses[0])


def physical_port(port: str, machine_id: str) -> str:
    """The physical port a record names, whatever spelling names it (``InvalidInput`` naming
    ``port`` when it is none): devices by their real path (symlinks and ``..`` resolved, under
    /dev); ``socket://`` and ``linuxcnc://`` as ``tcp://<host>:<port>`` with the host resolved
    (every loopback name is ``loopback``; the scheme and ``?joints=`` do not name another
    controller); ``mock://`` and ``loop://`` one per record."""
    parts = PortUrl.parse(port)
    if parts.is_mock:
        return f"mock:{machine_id}"
    if parts.is_tcp:  # a TCP controller: linuxcncrsh, a serial bridge
        host, number = parts.host, parts.port
        query_ok = not parts.query or (parts.scheme == "linuxcnc" and re.fullmatch(r"joints=\d", parts.query))
        if not host or number is None or not 0 < number < 65536 or parts.path not in ("", "/") or not query_ok:
            raise InvalidInput(f"expected {parts.scheme}://host:port, got {port!r}", field="port", value=port)
        return f"tcp://{_tcp_host(host, port)}:{number}"
    if parts.scheme == "loop":
        return f"loop:{machine_id}"
    if port.startswith("/dev/"):
        real = os.path.realpath(port)
        if not real.startswith("/dev/") or real == "/dev/":
            raise InvalidInput(f"device {port!r} resolves to {real!r}, which is not under /dev", field="port",
                               value=port)
        check_serial_device(real, port)
        return real
    if re.fullmatch(r"COM\d+", port, flags=re.IGNORECASE):
        return port.upper()
    raise InvalidInput("expected mock://..., socket://host:port, linuxcnc://host:port or a device under /dev",
                       field="port", value=port)


def port_key(port: str, machine_id: str, socket_hosts: tuple[str, ...]) -> str:
    """:func:`physical_port` of a new record (stored under a unique constraint, so that two
    records can never name one controller); a ``socket://`` or ``linuxcnc://`` host must be
    in ``socket_hosts`` (settings), compared lower-cased."""
    parts = PortUrl.parse(port)
    key = physical_port(port, machine_id)
    if parts.is_tcp:
        host = parts.host
        allowed = {h.lower() for h in socket_hosts}
        if host not in allowed:
            raise InvalidInput(f"{parts.scheme} host {host!r} is not in the allow-list (CONFORMA_SOCKET_HOSTS: "
                               f"{', '.join(sorted(allowed)) or 'empty'})", field="port", value=port)
    return key


def port_owner(key: str, records: Iterable[tuple[str, str]]) -> str | None:
    """The id among ``records`` (id, port) whose port is the physical port ``key`` (records
    stored before a spelling was normalised included), else None."""
    for machine_id, port in records:
        try:
            if physical_port(port, machine_id) == key:
                return machine_id
        except InvalidInput:
            continue
    return None


#: character-device majors of UNIX98 pseudo-terminal ends (they have no entry in sysfs)
PTY_MAJORS = range(136, 144)


def check_serial_device(real: str, port: str) -> None:
    """Refuse a device the kernel does not call a terminal: it must exist, be a character
    device, and be of the ``tty`` class in sysfs (``/sys/dev/char/MAJOR:MINOR/subsystem``) or
    a pseudo-terminal (majors 136-143).  So ``/dev/mem`` (mem class), ``/dev/watchdog``
    (misc) or a disk are refused whatever they are named."""
    try:
        st = os.stat(real)
    except OSError as exc:
        raise InvalidInput(f"device {port!r} cannot be opened: {exc.strerror}", field="port", value=port) from None
    if not stat.S_ISCHR(st.st_mode):
        raise InvalidInput(f"device {port!r} is not a character device (a serial port is one)", field="port",
                           value=port)
    major, minor = os.major(st.st_rdev), os.minor(st.st_rdev)
    if major in PTY_MAJORS:
        return
    try:
        subsystem = os.path.basename(os.readlink(f"/sys/dev/char/{major}:{minor}/subsystem"))
    except OSError:
        subsystem = "unknown"
    if subsystem != "tty":
        raise InvalidInput(f"device {port!r} is not a serial port: the kernel lists it as {subsystem!r} "
                           f"(character device {major}:{minor}), not tty", field="port", value=port)


class MachineManager:
    """Machine objects by id; builds mock worlds; one lock per registry change."""

    def __init__(self, load_mesh: Any, linuxcnc: dict[str, str] | None = None) -> None:
        # LinuxCNCMachine keywords: connect_pw, enable_pw, program_dir
        self._linuxcnc: dict[str, Any] = dict(linuxcnc or {})
        self._machines: dict[str, Machine] = {}
        self.running_job: dict[str, str] = {}  # machine id -> id of the job driving it (read-only: use lease)
        self._lock = threading.Lock()
        self._load_mesh = load_mesh  # part_id -> trimesh
        # emergency stops write through these threads: never the request thread pool
        self.stop_pool = ThreadPoolExecutor(max_workers=4, thread_name_prefix="estop")

    def get(self, machine_id: str) -> Machine | None:
        with self._lock:
            return self._machines.get(machine_id)

    @contextmanager
    def lease(self, machine_id: str, job_id: str) -> Iterator[None]:
        """Job ``job_id`` drives machine ``machine_id`` inside the ``with`` block.

        Records the job in :attr:`running_job` (what the machines page shows as the
        program's job), refuses a machine leased by another job (409 Conflict naming
        ``params.machine_id``) and always releases it on exit, whether the block ends, raises
        or is cancelled: what a failed or interrupted job does next (it stops and waits for
        an operator) is the job's recovery, not the lease's.  Re-entrant for the same job:
        an inner lease of a machine the job already holds leaves the outer one in place.
        """
        with self._lock:
            holder = self.running_job.get(machine_id)
            if holder is not None and holder != job_id:
                raise Conflict(f"machine {machine_id!r} is busy with job {holder}; one program at a time",
                               field="params.machine_id", value=machine_id)
            self.running_job[machine_id] = job_id
        try:
            yield
        finally:
            if holder is None:
                with self._lock:
                    if self.running_job.get(machine_id) == job_id:
                        del self.running_job[machine_id]

    def require(self, machine_id: str) -> Machine:
        machine = self.get(machine_id)
        if machine is None or machine.state == "disconnected":
            raise Conflict(f"machine {machine_id!r} is not connected", field="machine_id", value=machine_id)
        return machine

    def world_by_id(self, machine_id: str) -> MockWorld | None:
        """The mock world of a connected mock machine, by id (None otherwise)."""
        machine = self.get(machine_id)
        if machine is None or not PortUrl.parse(machine.url).is_mock:
            return None
        from hardware.mock import get_world

        try:
            return get_world(machine_id)
        except KeyError:
            return None

    def world(self, row: MachineRow) -> MockWorld | None:
        """The mock world of a mock machine (None for real ports)."""
        if not PortUrl.parse(row.port).is_mock:
            return None
        from hardware.mock import get_world

        try:
            return get_world(row.id)
        except KeyError:
            return None

    def _build_world(self, row: MachineRow) -> None:
        mock = row.mock or {}
        placement = mock.get("placement") or {}
        faults = mock.get("faults") or {}
        true_part_id = mock.get("true_part_id")
        profile = row.profile or {}
        world = MockWorld(
            true_part=self._load_mesh(true_part_id) if true_part_id else None,
            placement=TruePlacement(**placement),
            probe_noise_mm=float(mock.get("probe_noise_mm", 0.0)),
            probe_dust=tuple((float(x), float(y), float(dz)) for x, y, dz in mock.get("probe_dust") or ()),
            seed=int(faults.get("seed", mock.get("seed", 0))),
            dialect=row.dialect,
            time_scale=float(mock.get("time_scale", 0.0)),
            faults=FaultConfig(**faults),
            dispense_on=profile.get("dispense_on"),
            dispense_off=profile.get("dispense_off"),
            **physics_kwargs(mock.get("physics")),
        )
        register_world(row.id, world)

    def build(self, row: MachineRow) -> Machine:
        """The machine object of ``row`` (made, not connected, on first use)."""
        with self._lock:
            machine: Machine | None = self._machines.get(row.id)
            if machine is None:
                with hardware_errors():
                    port = PortUrl.parse(row.port)
                    if port.is_mock and self.world(row) is None:
                        self._build_world(row)
                    if port.scheme == "linuxcnc":  # LinuxCNC over linuxcncrsh
                        from hardware.linuxcnc import LinuxCNCMachine

                        machine = LinuxCNCMachine(row.port, profile_of(row), **self._linuxcnc)
                    else:
                        machine = SerialMachine(port_url(row), row.dialect, profile_of(row), baudrate=row.baudrate,
                                          boot_wait_s=0.0 if port.is_mock else 2.0)
                self._machines[row.id] = machine
        return machine

    def connect(self, row: MachineRow) -> Machine:
        """Connect (again) and identify; the mock world is kept across reconnects.  A 409
        naming the other record when another record's connection holds the same physical
        port (records stored before their spellings were normalised)."""
        key = physical_port(row.port, row.id)
        with self._lock:
            live = {machine_id: machine.url for machine_id, machine in self._machines.items()
                    if machine_id != row.id and machine.state != "disconnected"}
        holder = port_owner(key, live.items())
        if holder is not None:
            raise Conflict(f"port {row.port!r} is machine {holder!r}'s, which is connected: one machine per "
                           "physical port (disconnect it, or delete the duplicate record)", field="port",
                           value=row.port)
        machine = self.build(row)
        with hardware_errors():
            machine.connect()
        return machine

    def disconnect(self, machine_id: str) -> None:
        machine = self.get(machine_id)
        if machine is not None:
            with hardware_errors():
                machine.disconnect()

    def forget(self, machine_id: str) -> None:
        with self._lock:
            machine = self._machines.pop(machine_id, None)
        if machine is not None and machine.state != "disconnected":
            machine.disconnect()
        unregister_world(machine_id)

    def close_all(self) -> None:
        with self._lock:
            machines = list(self._machines.values())
        for machine in machines:
            try:
                if machine.state != "disconnected":
                    machine.disconnect()
            except HardwareError:
                pass



def physics_kwargs(physics: dict[str, Any] | None) -> dict[str, Any]:
    """``MockWorld`` keyword arguments from a stored ``mock.physics`` (``MockPhysics``) dict."""
    if not physics:
        return {}
    kwargs: dict[str, Any] = {name: float(physics.get(name, 0.0)) for name in (
        "stylus_radius_mm", "pretravel_mm", "pretravel_sd_mm", "pretravel_lobing_mm",
        "drift_mm_per_min", "touchoff_sd_mm")}
    kwargs["tools"] = tuple(MockTool(tuple(t["offset_mm"]), t["outer_diameter_mm"])
                            for t in physics.get("tools") or ())
    if physics.get("pad"):
        kwargs["pad"] = MockPad(tuple(physics["pad"]["centre_mm"]), physics["pad"]["size_mm"])
    if physics.get("sphere"):
        kwargs["sphere"] = MockSphere(tuple(physics["sphere"]["centre_mm"]), physics["sphere"]["diameter_mm"])
    return kwargs
