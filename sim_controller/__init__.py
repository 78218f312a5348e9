"""sim_controller: a simulated CMM controller and a simulated "true" machine.

The true machine is the parametric model plus optional hidden effects and noise; the controller
runs probing programs (ISO 10360-2 length test, ball plate, random points, measurement sessions),
sends raw readings and temperatures over CAN or Modbus as a real peer, and evaluates the answers.
"""

from __future__ import annotations

from .controller import AnswerRecord, CanController, RawReading
from .iso10360 import LengthMeasurement, e0_um, length_errors_um, length_test
from .modbus_controller import ModbusController
from .programs import BallPlate, ProbePoint, random_points
from .runner import Program, build_program, evaluate, make_readings, run_can
from .sessions import SessionPlan, measure_session, plan_session
from .sim_machine import Environment, SimulatedMachine
from .true_machine import TrueMachine, random_effect, simulate

__all__ = [
    "AnswerRecord",
    "BallPlate",
    "CanController",
    "Environment",
    "LengthMeasurement",
    "ModbusController",
    "ProbePoint",
    "Program",
    "RawReading",
    "SessionPlan",
    "SimulatedMachine",
    "TrueMachine",
    "build_program",
    "e0_um",
    "evaluate",
    "length_errors_um",
    "length_test",
    "make_readings",
    "measure_session",
    "plan_session",
    "random_effect",
    "random_points",
    "run_can",
    "simulate",
]
