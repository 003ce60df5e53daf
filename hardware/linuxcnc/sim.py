"""Start and stop Conforma's headless LinuxCNC simulators (``sim/xyz.ini``, ``sim/xyzac-trt.ini``).

    with SimController("xyzac-trt", pivot_mm=(0, 0, 0)) as sim:
        machine = sim.machine()              # a LinuxCNCMachine on sim.url
        ...

LinuxCNC allows one instance per host.  Where the host permits it (root), each simulator runs
in namespaces of its own (:mod:`hardware.linuxcnc.sim_namespace`), so several run at once,
and HAL commands enter its namespace (``hal_env`` carries the prefix,
:mod:`hardware.linuxcnc.hal_command`).  Elsewhere a ``SimController`` holds an exclusive
lock (``/tmp/conforma-linuxcnc.lock``) from start to stop, so two of them (two test
processes) wait for each other instead of killing each other's controller (LinuxCNC's own
clean-up ends processes *by name*).

Each start copies the config into a fresh directory (LinuxCNC writes its parameter file
and a HAL dump next to the INI), fills in a free port and fresh random linuxcncrsh
passwords, and runs ``linuxcnc <ini>`` in its own process group.  As root, LinuxCNC's
uspace realtime needs ``RTAPI_UID`` (an unprivileged uid: ``CONFORMA_RTAPI_UID`` or
``nobody``) and ``RTAPI_FIFO_PATH`` in a directory that uid owns; both are set here.
linuxcncrsh listens on every interface (it has no bind option): the random passwords and
a port chosen per run are the only guard here; firewall the port on shared hosts.

Once linuxcncrsh answers, the HAL threads are given a real-time priority where the host
permits it (:mod:`hardware.linuxcnc.sim_realtime`: a controller's servo thread does not wait
for a busy host's scheduler); ``realtime_threads`` / ``realtime_note`` say what was done.

Stop: ``shutdown`` over linuxcncrsh (about 3 s), then SIGTERM / SIGKILL to the process
group this object started (never to processes found by name).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import pwd
import secrets
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from pathlib import Path
from typing import IO

from ..errors import HardwareError, LinkError
from ..machine_types import MachineProfile
from .hal_command import HAL_PREFIX_VAR, hal_command
from .hal_watcher import HalWatch, SimUnavailable
from .machine import LinuxCNCMachine
from .rsh import RshSession
from .sim_namespace import SYSTEM_NML, isolation_available, launch_command, nsenter_prefix, write_nml
from .sim_realtime import ipc_namespace_of, servo_threads_realtime
from .sim_surface import SimBlock, SimSensor, SimSphere

__all__ = ["CONFIGS", "HalWatch", "SimBlock", "SimController", "SimSensor", "SimSphere", "SimUnavailable",
           "linuxcnc_available"]

SIM_DIR = Path(__file__).with_name("sim")
CONFIGS = {"xyz": "xyz.ini", "xyzac-trt": "xyzac-trt.ini"}
SENSOR_COMPONENT = Path(__file__).with_name("sensor_hal.py")  # sim/sensor.hal's component
SENSOR_MAP = "sensor_map.npz"  # in the run's directory: the jetted ink the sensor sees
LOCK_PATH = os.path.join(tempfile.gettempdir(), "conforma-linuxcnc.lock")


def linuxcnc_available() -> bool:
    """True when the ``linuxcnc`` launcher and ``linuxcncrsh`` are on PATH."""
    return shutil.which("linuxcnc") is not None and shutil.which("linuxcncrsh") is not None


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _number_or_text(value: str) -> float | str:
    """A HAL value as a float when it is one (so -0 equals 0), else as printed (TRUE/FALSE)."""
    try:
        return float(value)
    except ValueError:
        return value


def _ipc_namespace(pid: int) -> str:
    """The ``/proc/<pid>/ns/ipc`` link of process ``pid`` (``ipc:[<inode>]``)."""
    namespace = ipc_namespace_of(Path(f"/proc/{pid}"))
    if namespace is None:
        raise SimUnavailable("the simulator's namespace is gone", field="linuxcnc", value=pid)
    return namespace


def _rtapi_uid() -> int:
    value = os.environ.get("CONFORMA_RTAPI_UID")
    return int(value) if value else pwd.getpwnam("nobody").pw_uid


class SimController:
    """One simulator run (see the module docstring).  ``pivot_mm`` is the xyzac-trt table
    pivot (ignored by the three-axis config)."""

    def __init__(self, config: str = "xyz", *, pivot_mm: tuple[float, float, float] = (0.0, 0.0, 0.0),
                 lock_timeout_s: float = 600.0) -> None:
        if config not in CONFIGS:
            raise ValueError(f"unknown simulator config {config!r}; expected one of {sorted(CONFIGS)}")
        self.config = config
        self.pivot_mm = tuple(float(v) for v in pivot_mm)
        self.lock_timeout_s = lock_timeout_s
        self.port = 0
        self.connect_pw = secrets.token_hex(7)  # linuxcncrsh keeps 15 characters
        self.enable_pw = secrets.token_hex(7)
        self.workdir: Path | None = None
        self.startup_s: float | None = None
        # the HAL threads made real-time after the start (sim_realtime), and why not when none
        self.realtime_threads = 0
        self.realtime_note: str | None = None
        # in namespaces of its own (sim_namespace): the /proc/<pid>/ns/ipc link of its IPC namespace
        self.ipc_namespace: str | None = None
        self._process: subprocess.Popen | None = None
        self._env: dict[str, str] | None = None
        self._lock_file: IO[str] | None = None

    # ------------------------------------------------------------------ public
    @property
    def url(self) -> str:
        """``linuxcnc://127.0.0.1:<port>?programs=<workdir>/programs&joints=<n>``."""
        return f"linuxcnc://127.0.0.1:{self.port}?programs={self.workdir}/programs&joints={self.joints}"

    def machine(self, profile: MachineProfile | None = None, **kwargs) -> LinuxCNCMachine:
        """A (not yet connected) machine on this simulator."""
        return LinuxCNCMachine(self.url, profile, connect_pw=self.connect_pw,
                               enable_pw=self.enable_pw, **kwargs)

    def session(self, enable: bool = False) -> RshSession:
        """A raw linuxcncrsh session (tests: an independent observer)."""
        session = RshSession.open("127.0.0.1", self.port, self.connect_pw, client="observer")
        if enable:
            session.enable(self.enable_pw)
        return session

    def set_surface(self, surface: SimBlock | SimSphere) -> None:
        """Make the simulated probe touch ``surface`` (a block or plane, or the reference
        sphere beside it; ``halcmd setp`` on the running simulator; see
        :mod:`hardware.linuxcnc.sim_surface`); on the three-axis simulator the height
        sensor sees the same block."""
        values = surface.setp_values()
        if self.has_sensor:
            values.update(surface.sensor_setp_values())
        self._setp(values)

    def set_sensor(self, sensor: SimSensor) -> None:
        """Set the simulated height sensor's optics (three-axis simulator, ``sim/sensor.hal``)."""
        if not self.has_sensor:
            raise SimUnavailable(f"the {self.config} simulator has no height sensor", field="config",
                                 value=self.config)
        self._setp(sensor.setp_values())

    @property
    def has_sensor(self) -> bool:
        """True for the config with the height sensor component (three-axis)."""
        return self.config == "xyz"

    @property
    def sensor_map(self) -> Path:
        """The height map file of the jetted ink the sensor sees (``sensor_hal.py``)."""
        assert self.workdir is not None, "start the simulator first"
        return self.workdir / SENSOR_MAP

    @property
    def hal_env(self) -> dict[str, str] | None:
        """The environment ``halcmd`` / ``halsampler`` need for this simulator."""
        return self._env

    def _hal_run(self, args: list[str], timeout_s: float) -> subprocess.CompletedProcess[str]:
        """Run a HAL command (``halcmd``, LinuxCNC's Python) at this simulator (text output)."""
        return subprocess.run(hal_command(args, self._env), capture_output=True, text=True, timeout=timeout_s,
                              env=self._env)

    def _setp(self, values: dict[str, float]) -> None:
        """``setp`` each value in one ``halcmd -f`` run."""
        if not self.running:
            raise SimUnavailable("the simulator is not running", field="linuxcnc")
        assert self.workdir is not None  # set while running
        script = self.workdir / "setp.hal"
        script.write_text("".join(f"setp {name} {float(value)!r}\n" for name, value in values.items()))
        done = self._hal_run(["halcmd", "-f", str(script)], timeout_s=10)
        if done.returncode != 0:
            raise SimUnavailable(f"halcmd setp failed: {done.stderr.strip()[:200]}", field="halcmd",
                                 value=sorted(values)[0])

    def watch(self, names: list[str], period_s: float = 0.0005, max_s: float = 300.0) -> HalWatch:
        """Start sampling HAL pins / ``task_state`` at the controller (``hal_watch.py``
        under the system Python); use as a context manager, samples in ``.samples``."""
        if not self.running:
            raise SimUnavailable("the simulator is not running", field="linuxcnc")
        return HalWatch(names, self._env, period_s, max_s)

    _OUTPUTS = ("import json, linuxcnc\n"
                "s = linuxcnc.stat(); s.poll()\n"
                "print(json.dumps({'dout': [int(v) for v in s.dout[:4]], 'spindle': int(s.spindle[0]['enabled']),\n"
                "                  'mist': int(s.mist), 'flood': int(s.flood), 'task_state': s.task_state}))\n")

    def outputs(self) -> dict:
        """The process outputs by LinuxCNC's own status (``linuxcnc.stat()`` under the system
        Python): ``{"dout": [4 motion digital outputs], "spindle", "mist", "flood"}`` as 0/1,
        and ``task_state`` (1 = e-stop)."""
        if not self.running:
            raise SimUnavailable("the simulator is not running", field="linuxcnc")
        python = shutil.which("python3", path="/usr/bin:/bin") or "python3"
        done = self._hal_run([python, "-c", self._OUTPUTS], timeout_s=20)
        if done.returncode != 0:
            raise SimUnavailable(f"reading linuxcnc.stat failed: {done.stderr.strip()[-300:]}", field="linuxcnc")
        return json.loads(done.stdout)

    @property
    def running(self) -> bool:
        return self._process is not None and self._process.poll() is None

    def task_pids(self) -> list[int]:
        """The pids of this simulator's task processes (``milltask`` in its IPC namespace; the
        host's when it shares that): empty once the task died."""
        namespace = self.ipc_namespace or ipc_namespace_of(Path("/proc/self"))
        found = []
        for pid in Path("/proc").iterdir():
            with contextlib.suppress(OSError):
                if pid.name.isdigit() and (pid / "comm").read_text().strip() == "milltask" \
                        and ipc_namespace_of(pid) == namespace:
                    found.append(int(pid.name))
        return found

    def __enter__(self) -> SimController:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ------------------------------------------------------------------ reuse
    # the HAL values :meth:`snapshot` reads: the probe surface and sphere (sim/probe.hal)
    # and the dispense output (M64/M65 P0)
    SNAPSHOT_HAL = (*SimBlock.plane(0.0, 0.0).setp_values(), *SimSphere.none().setp_values(),
                    "motion.digital-out-00")
    SNAPSHOT_SENSOR = (*SimBlock.plane(0.0, 0.0).sensor_setp_values(), *SimSphere.none().sensor_setp_values(),
                       *SimSensor().setp_values())
    # (not "tool_offset": linuxcncrsh 2.9 answers it with an arbitrary integer, -1163042392
    # after one start, 115 after another; the tests apply no tool-length offset, G43)
    SNAPSHOT_RSH = ("estop", "machine", "mode", "joint_homed", "program_status", "program_codes",
                    "program_units", "tool", "kinematics_type")

    def snapshot(self) -> dict[str, float | str]:
        """The controller's state a test could inherit, as the controller and HAL report it:
        ``SNAPSHOT_RSH`` (linuxcncrsh ``get``: e-stop, power, task mode, homed joints,
        program status, active G/M codes, units, tool, kinematics) and
        ``SNAPSHOT_HAL`` (``halcmd getp``: the probe surface, the sphere, the dispense
        output; with the height sensor also ``SNAPSHOT_SENSOR``: its surface and optics pins).
        Joint positions are not part of it (every test homes first)."""
        if not self.running:
            raise SimUnavailable("the simulator is not running", field="linuxcnc")
        session = self.session()
        try:
            state: dict[str, float | str] = {name: session.get(name) for name in self.SNAPSHOT_RSH}
        finally:
            session.close()
        assert self.workdir is not None  # set while running
        script = self.workdir / "snapshot.hal"
        names = self.SNAPSHOT_HAL + (self.SNAPSHOT_SENSOR if self.has_sensor else ())
        script.write_text("".join(f"getp {name}\n" for name in names))
        done = self._hal_run(["halcmd", "-f", str(script)], timeout_s=10)
        values = done.stdout.split()
        if done.returncode != 0 or len(values) != len(names):
            raise SimUnavailable(f"halcmd getp failed: {done.stderr.strip()[:200]}", field="halcmd")
        state.update(zip(names, (_number_or_text(v) for v in values)))
        return state

    def reset(self, timeout_s: float = 30.0) -> None:
        """Bring the running simulator back to its start-up state without a restart (a
        restart costs 7 s on a quiet box, over a minute on a loaded one): abort whatever
        runs, dispense output off and no tool (by MDI, when the joints are homed), the
        interpreter re-initialised (``task_plan_init``: units, distance mode, offsets, as
        at start-up), the controller's unread errors dropped, every joint un-homed
        (``unhome`` through LinuxCNC's Python module under the system Python), the probe
        surface and sphere of ``sim/probe.hal``'s start-up values, manual mode, e-stop on.
        It does not move the joints.  Callers compare :meth:`snapshot` with the one taken
        right after start (the test fixtures restart the simulator when they differ)."""
        if not self.running:
            raise SimUnavailable("the simulator is not running", field="linuxcnc")
        z0, slope_x = self.start_surface()
        self.set_surface(SimBlock.plane(z0, slope_x))
        self.set_surface(SimSphere.none())
        if self.has_sensor:
            self.set_sensor(SimSensor())
            self._setp_signal_off()
            self.sensor_map.unlink(missing_ok=True)
        session = self.session(enable=True)
        try:
            session.set("estop", "off")
            session.set("machine", "on")
            session.set("abort")
            session.set("wait", "done", timeout_s=timeout_s)
            if all(h.upper() == "YES" for h in session.get("joint_homed").split()[:self.joints]):
                session.set("mode", "mdi")
                for command in ("M65 P0", "T0 M6"):
                    session.set("mdi", command)
                    session.set("wait", "done", timeout_s=timeout_s)
            session.set("mode", "manual")
            session.set("task_plan_init")
            session.set("wait", "done", timeout_s=timeout_s)
            self._unhome(timeout_s)
            session.set("mode", "manual")
            session.set("estop", "on")
            for _ in range(100):
                if session.pop_error() is None:
                    break
        finally:
            session.close()

    def _setp_signal_off(self) -> None:
        """The height sensor and its sampler off (``sets conforma:sensor-on 0``)."""
        self._hal_run(["halcmd", "sets", "conforma:sensor-on", "0"], timeout_s=10)

    _UNHOME = ("import linuxcnc, sys\n"
               "c = linuxcnc.command()\n"
               "c.mode(linuxcnc.MODE_MANUAL); c.wait_complete()\n"
               "c.teleop_enable(0); c.wait_complete()\n"
               "c.unhome(-1); sys.exit(0 if c.wait_complete() != -1 else 1)\n")

    def _unhome(self, timeout_s: float) -> None:
        python = shutil.which("python3", path="/usr/bin:/bin") or "python3"
        done = self._hal_run([python, "-c", self._UNHOME], timeout_s=timeout_s)
        if done.returncode != 0:
            raise SimUnavailable(f"unhome failed: {done.stderr.strip()[-300:]}", field="linuxcnc")

    def start_surface(self) -> tuple[float, float]:
        """The start-up probe plane of this config, ``([CONFORMA] SURFACE_Z, SURFACE_SLOPE_X)``
        of its INI (mm, mm/mm)."""
        section, values = "", {}
        for raw in (SIM_DIR / CONFIGS[self.config]).read_text().splitlines():
            line = raw.strip()
            if line.startswith("["):
                section = line
            elif section == "[CONFORMA]" and line.startswith("SURFACE_"):
                key, _, value = line.partition("=")
                values[key.strip()] = float(value)
        return values["SURFACE_Z"], values["SURFACE_SLOPE_X"]

    @property
    def joints(self) -> int:
        """Number of joints of this config."""
        return 5 if self.config == "xyzac-trt" else 3

    # ------------------------------------------------------------------ start
    def _lock(self) -> None:
        self._lock_file = open(LOCK_PATH, "a+")
        deadline = time.monotonic() + self.lock_timeout_s
        while True:
            try:
                fcntl.flock(self._lock_file, fcntl.LOCK_EX | fcntl.LOCK_NB)
                return
            except BlockingIOError:
                if time.monotonic() > deadline:
                    self._unlock()
                    raise SimUnavailable("another LinuxCNC simulator holds the lock", field="lock",
                                         value=LOCK_PATH) from None
                time.sleep(0.2)

    def _unlock(self) -> None:
        if self._lock_file is not None:
            fcntl.flock(self._lock_file, fcntl.LOCK_UN)
            self._lock_file.close()
            self._lock_file = None

    def _prepare(self) -> tuple[Path, dict[str, str]]:
        workdir = Path(tempfile.mkdtemp(prefix=f"conforma-lcnc-{self.config}-"))
        shutil.copytree(SIM_DIR, workdir, dirs_exist_ok=True)
        (workdir / "programs").mkdir()
        fields = {"PORT": str(self.port), "CONNECTPW": self.connect_pw, "ENABLEPW": self.enable_pw,
                  "PIVOT_X": repr(self.pivot_mm[0]), "PIVOT_Y": repr(self.pivot_mm[1]),
                  "PIVOT_Z": repr(self.pivot_mm[2]), "SENSOR_COMPONENT": str(SENSOR_COMPONENT),
                  "SENSOR_MAP": str(workdir / SENSOR_MAP), "NML_FILE": str(SYSTEM_NML)}
        if SYSTEM_NML.exists():  # its NML server on a port of its own (several simulators per host)
            write_nml(workdir / "linuxcnc.nml", _free_port())
            fields["NML_FILE"] = str(workdir / "linuxcnc.nml")
        ini = workdir / CONFIGS[self.config]
        text = ini.read_text()
        for key, value in fields.items():
            text = text.replace(f"@{key}@", value)
        ini.write_text(text)
        ini.chmod(0o600)       # it holds the linuxcncrsh passwords
        workdir.chmod(0o711)   # the realtime process (RTAPI_UID) must reach rtapi/
        env = dict(os.environ)
        env.pop("DISPLAY", None)
        # LinuxCNC maps its tool table from $HOME/.tool.mmap: simulators sharing a HOME share the
        # file, and one starting or stopping resizes it under the other's task (SIGBUS)
        env["HOME"] = str(workdir)
        if os.geteuid() == 0:
            uid = _rtapi_uid()
            fifo_dir = workdir / "rtapi"
            fifo_dir.mkdir()
            os.chown(fifo_dir, uid, -1)
            env["RTAPI_UID"] = str(uid)
            env["RTAPI_FIFO_PATH"] = str(fifo_dir / "rtapi_fifo")
        return workdir, env

    def start(self, timeout_s: float = 60.0) -> None:
        """Start LinuxCNC and wait until linuxcncrsh answers ``hello``."""
        if not linuxcnc_available():
            raise SimUnavailable("LinuxCNC is not installed (Debian: apt-get install linuxcnc-uspace)",
                                 field="linuxcnc")
        isolated = isolation_available()
        if not isolated:
            self._lock()
        started = time.monotonic()
        try:
            self.port = _free_port()
            self.workdir, env = self._prepare()
            self._env = env
            command = ["linuxcnc", CONFIGS[self.config]]
            if isolated:
                command = launch_command(self.workdir, CONFIGS[self.config])
            log = open(self.workdir / "linuxcnc.log", "wb")
            self._process = subprocess.Popen(command, cwd=self.workdir, env=env, stdout=log, stderr=subprocess.STDOUT,
                                             stdin=subprocess.DEVNULL, start_new_session=True)
            log.close()
            self._await_hello(self._process, started + timeout_s)
            if isolated:  # (unshare has entered its namespaces once linuxcncrsh answers)
                self._env = {**env, HAL_PREFIX_VAR: nsenter_prefix(self._process.pid)}
                self.ipc_namespace = _ipc_namespace(self._process.pid)
            self.realtime_threads, self.realtime_note = servo_threads_realtime(ipc_namespace=self.ipc_namespace)
        except BaseException:
            self.stop()
            raise
        self.startup_s = time.monotonic() - started

    def _await_hello(self, process: subprocess.Popen[bytes], deadline: float) -> None:
        while time.monotonic() < deadline:
            if process.poll() is not None:
                raise SimUnavailable(f"LinuxCNC exited with {process.returncode}: "
                                     f"{self.log_tail()}", field="linuxcnc")
            try:
                self.session().close()
                return
            except LinkError:
                time.sleep(0.25)
        raise SimUnavailable(f"linuxcncrsh did not answer in time: {self.log_tail()}", field="linuxcnc")

    def log_tail(self, chars: int = 600) -> str:
        """The end of LinuxCNC's console output."""
        if self.workdir is None:
            return ""
        try:
            return (self.workdir / "linuxcnc.log").read_text(errors="replace")[-chars:]
        except (OSError, TypeError):
            return ""

    # ------------------------------------------------------------------ stop
    def stop(self, timeout_s: float = 20.0) -> None:
        """Shut LinuxCNC down (``shutdown``, then signals to our own process group)."""
        process, self._process = self._process, None
        try:
            if process is not None and process.poll() is None:
                try:
                    session = self.session(enable=True)
                    session.send_only("shutdown")
                    session.close()
                except (HardwareError, OSError):
                    pass
                self._wait_or_signal(process, timeout_s)
        finally:
            if self.workdir is not None:
                shutil.rmtree(self.workdir, ignore_errors=True)
            self._unlock()

    @staticmethod
    def _wait_or_signal(process: subprocess.Popen, timeout_s: float) -> None:
        for sig in (None, signal.SIGTERM, signal.SIGKILL):
            if sig is not None:
                try:
                    os.killpg(process.pid, sig)
                except ProcessLookupError:
                    return
            try:
                process.wait(timeout=timeout_s)
                return
            except subprocess.TimeoutExpired:
                continue
