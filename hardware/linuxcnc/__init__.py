"""LinuxCNC controllers over linuxcncrsh (``linuxcnc://host:port``) and Conforma's headless
LinuxCNC simulators (three-axis and five-axis xyzac-trt)."""

from .hal_watcher import HalWatch, SimUnavailable
from .machine import LinuxCNCMachine
from .rsh import RshRejected, RshSession
from .sim import SimController, linuxcnc_available
from .sim_surface import SimBlock, SimSensor, SimSphere
from .url import LinuxCNCAddress, parse_url

__all__ = ["HalWatch", "LinuxCNCAddress", "LinuxCNCMachine", "RshRejected", "RshSession", "SimBlock",
           "SimController", "SimSensor", "SimSphere", "SimUnavailable", "linuxcnc_available", "parse_url"]
