"""Public API of ``protocol`` (read by lazy_loader: names load on first use)."""

from .assembler import (
    AssemblerEvent,
    Duplicate,
    Incomplete,
    OutOfOrder,
    Superseded,
    Triplet,
    TripletAssembler,
)
from .can_codec import (
    BadLength,
    BadValue,
    DecodeResult,
    NotData,
    Undecodable,
    UnknownId,
    decode_message,
    encode_message,
)
from .can_frames import (
    CorrectedAxis,
    CorrectionStatus,
    Frame,
    Heartbeat,
    ProbeDirection,
    RawAxis,
    TemperatureSample,
    encode_corrected_axes,
    encode_correction_status,
)
from .can_ids import CanIds, MessageKind, dbc_text
from .codes import Applied, Axis, DaemonState, Direction, Status, grid_id_from_sha256, seq_distance
from .modbus_client import AnswerTimeoutError, ControllerClient, ModbusExceptionError
from .modbus_codec import AnswerBlock, DaemonBlock, ReadingBlock, TemperatureSlot, decode_output
from .modbus_device import build_sim_device
from .modbus_map import ExceptionCode, check_request, check_write, commits_reading

__all__ = [
    "AnswerBlock",
    "AnswerTimeoutError",
    "Applied",
    "AssemblerEvent",
    "Axis",
    "BadLength",
    "BadValue",
    "CanIds",
    "ControllerClient",
    "CorrectedAxis",
    "CorrectionStatus",
    "DaemonBlock",
    "DaemonState",
    "DecodeResult",
    "Direction",
    "Duplicate",
    "ExceptionCode",
    "Frame",
    "Heartbeat",
    "Incomplete",
    "MessageKind",
    "ModbusExceptionError",
    "NotData",
    "OutOfOrder",
    "ProbeDirection",
    "RawAxis",
    "ReadingBlock",
    "Status",
    "Superseded",
    "TemperatureSample",
    "TemperatureSlot",
    "Triplet",
    "TripletAssembler",
    "Undecodable",
    "UnknownId",
    "build_sim_device",
    "check_request",
    "check_write",
    "commits_reading",
    "dbc_text",
    "decode_message",
    "decode_output",
    "encode_corrected_axes",
    "encode_correction_status",
    "encode_message",
    "grid_id_from_sha256",
    "seq_distance",
]
