"""cosimstep: a co-simulation master for black-box dynamic sub-models.

The public API is small: build a :class:`System` (in code or with :func:`load_system`), pick a
master (:class:`MasterOptions`) and a step controller, call :func:`simulate`, get a
:class:`SimulationResult`.
"""

from cosimstep.adapters.ode import RK4, OdeSubModel, ParameterSchedule, SolveIvp
from cosimstep.config import SystemSpec, load_system
from cosimstep.controllers import Controller, Fixed, Random, make_controller
from cosimstep.errors import (
    ConfigurationError,
    Problem,
    RunInterrupted,
    StepSizeError,
    SubModelError,
)
from cosimstep.masters import DEFAULT_CALL_TIMEOUT, MasterOptions
from cosimstep.reference import Reference
from cosimstep.simulate import SimulationResult, simulate
from cosimstep.ssp import load_ssp
from cosimstep.store import read_run
from cosimstep.submodel import Capabilities, Port, SubModel
from cosimstep.sweep import sweep
from cosimstep.system import System

__all__ = [
    "DEFAULT_CALL_TIMEOUT", "RK4", "Capabilities", "ConfigurationError", "Controller", "Fixed",
    "MasterOptions",
    "OdeSubModel", "ParameterSchedule", "Port", "Problem", "Random", "Reference",
    "RunInterrupted",
    "SimulationResult", "SolveIvp", "StepSizeError", "SubModel", "SubModelError", "System",
    "SystemSpec", "load_ssp", "load_system", "make_controller", "read_run", "simulate", "sweep",
]
