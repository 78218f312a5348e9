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
from .can_answer import (
    encode_corrected_axes,
    encode_correction_status,
    encode_correction_uncertainty,
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
from .can_fd_frames import CorrectedReading, RawReading, encode_corrected_reading
from .can_frames import (
    CorrectedAxis,
    CorrectionStatus,
    CorrectionUncertainty,
    Frame,
    Heartbeat,
    ProbeDirection,
    RawAxis,
    TemperatureSample,
)
from .can_ids import CanIds, MessageKind, dbc_text, sent_by_daemon
from .codes import Applied, Axis, DaemonState, Direction, Status, grid_id_from_sha256, seq_distance
from .modbus_client import AnswerTimeoutError, ControllerClient, ModbusExceptionError
from .modbus_codec import AnswerBlock, DaemonBlock, ReadingBlock, TemperatureSlot, decode_output
from .modbus_device import Handled, MapDevice
from .modbus_devid import DeviceIdentity, device_id_response
from .modbus_map import ExceptionCode, check_request, check_write, commits_reading
from .modbus_pdu import FrameError, Request, parse_request
from .modbus_tcp import DIRECT_UNIT_IDS, MbapListener, MbapServer
from .session_topics import (
    RECORD_FIELDS,
    TOPIC_SCHEMAS,
    TOPIC_TYPES,
    TopicSchema,
    check_message,
    ns_from_can_timestamp,
    ns_from_stamp,
    stamp_from_ns,
)

__all__ = [
    "DIRECT_UNIT_IDS",
    "RECORD_FIELDS",
    "TOPIC_SCHEMAS",
    "TOPIC_TYPES",
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
    "CorrectedReading",
    "CorrectionStatus",
    "CorrectionUncertainty",
    "DaemonBlock",
    "DaemonState",
    "DecodeResult",
    "DeviceIdentity",
    "Direction",
    "Duplicate",
    "ExceptionCode",
    "Frame",
    "FrameError",
    "Handled",
    "Heartbeat",
    "Incomplete",
    "MapDevice",
    "MbapListener",
    "MbapServer",
    "MessageKind",
    "ModbusExceptionError",
    "NotData",
    "OutOfOrder",
    "ProbeDirection",
    "RawAxis",
    "RawReading",
    "ReadingBlock",
    "Request",
    "Status",
    "Superseded",
    "TemperatureSample",
    "TemperatureSlot",
    "TopicSchema",
    "Triplet",
    "TripletAssembler",
    "Undecodable",
    "UnknownId",
    "check_message",
    "check_request",
    "check_write",
    "commits_reading",
    "dbc_text",
    "decode_message",
    "decode_output",
    "device_id_response",
    "encode_corrected_axes",
    "encode_corrected_reading",
    "encode_correction_status",
    "encode_correction_uncertainty",
    "encode_message",
    "grid_id_from_sha256",
    "ns_from_can_timestamp",
    "ns_from_stamp",
    "parse_request",
    "sent_by_daemon",
    "seq_distance",
    "stamp_from_ns",
]
