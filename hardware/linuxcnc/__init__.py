"""LinuxCNC controllers over linuxcncrsh (``linuxcnc://host:port``) and Conforma's headless
LinuxCNC simulators (three-axis and five-axis xyzac-trt)."""

from .machine import LinuxCNCMachine
from .rsh import RshRejected, RshSession
from .sim import SimController, SimUnavailable, linuxcnc_available
from .sim_surface import SimBlock
from .url import LinuxCNCAddress, parse_url

__all__ = ["LinuxCNCAddress", "LinuxCNCMachine", "RshRejected", "RshSession", "SimBlock", "SimController",
           "SimUnavailable", "linuxcnc_available", "parse_url"]
