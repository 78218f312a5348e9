"""Replay a logged session: re-correct it offline (vectorised) or re-send it to a running daemon.

:func:`replay_offline` reads a session (one MCAP file, a directory of rolled files or a glob;
files cut by a crash read up to the break), pairs every ``/cmm/raw`` reading with the
``/cmm/corrected`` answer the daemon sent, rebuilds each reading's temperatures from the
``/cmm/temperature`` samples logged before it, re-corrects all readings in one call of
``CorrectionGrid.correct`` with the session's grid or another one, and reports the differences
(µm) from what was sent: of the corrected positions, and of the expanded uncertainty U
(``ux_um``/``uy_um``/``uz_um``) where both the session and the replay know it, with the count
of readings where only one of them does.

:func:`replay_to_bus` re-sends the frames the controller sent (``/cmm/can_rx`` frames with
``direction`` ``rx``: readings, probing directions and temperatures, byte-exact) at the
recorded pace (or faster) to a daemon on any python-can bus. The daemon's own frames are never
re-sent: on ``udp_multicast`` every node receives its own frames back, so ``/cmm/can_rx`` also
holds the daemon's answers, statuses and heartbeats (``direction`` ``tx_echo``), and a
controller on the replay's bus would take those stale answers for live ones. A log written
before frames carried their direction is sorted by CAN id ownership instead (the DBC's
transmitter of each message, :func:`cmm_comp.protocol.can_ids.sent_by_daemon`), and the report
says so.
"""

from __future__ import annotations

import time
from collections import defaultdict, deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import numpy as np

from cmm_comp.compensation.errors import CmmCompError
from cmm_comp.compensation.grid import CorrectionGrid
from cmm_comp.compensation.thermal import TEMPERATURE_ROLES
from cmm_comp.daemon.engine import GRID_STATUS
from cmm_comp.protocol.can_ids import sent_by_daemon
from cmm_comp.protocol.codes import Status
from cmm_comp.protocol.session_topics import ns_from_stamp

from .reader import read_messages

_GEOMETRY_APPLIED = tuple(s.label for s in Status if s.geometric_correction_applied)


class ReplayError(CmmCompError, ValueError):
    """The session cannot be replayed (message names the file and the problem)."""


@dataclass
class ReplayReport:
    """What re-correcting a session found. Differences are replayed − sent, µm."""

    session: list[str]
    truncated: bool
    grid_path: str
    grid_sha256: str
    session_grid_sha256: str
    readings: int
    compared: int
    """Readings where both the sent answer and the replay applied the geometry."""
    max_abs_diff_um: float
    rms_diff_um: float
    status_agree: int
    status_differ: dict[str, int] = field(default_factory=dict)
    """``"sent→replayed"`` → count."""
    sent_statuses: dict[str, int] = field(default_factory=dict)
    replayed_statuses: dict[str, int] = field(default_factory=dict)
    diffs_um: np.ndarray | None = None
    """(compared, 3) differences, µm (not in :meth:`as_dict`)."""
    read_error: str | None = None
    """Where and why a cut file stopped reading (None when every file was complete)."""
    grid_has_uncertainty: bool = False
    """The replay's grid carries U."""
    sent_uncertainty_known: int = 0
    """Answers logged with a U (numbers in ``ux_um``…)."""
    replayed_uncertainty_known: int = 0
    """Readings the replay gave a U (status ``ok`` and a grid carrying U)."""
    uncertainty_compared: int = 0
    """Readings whose U both the session and the replay know."""
    max_abs_u_diff_um: float = float("nan")
    """Largest |replayed U − sent U| over those readings and components, µm."""
    uncertainty_mismatch: int = 0
    """Readings whose U only one side knows (e.g. another grid with or without U, a status
    that differs, a correction the daemon refused by its limits)."""
    sent_not_finite: int = 0
    """Answers logged as corrected whose position is not a finite number (only a damaged or
    hand-made log holds one: the logger never writes them): not compared, counted here."""

    @property
    def warning(self) -> str | None:
        """One line for the user when the session was cut by a crash or holds corrected answers
        that are not numbers, else None."""
        lines = []
        if self.truncated:
            lines.append(
                f"session cut by a crash: replayed the {self.readings} readings read before the "
                f"break ({self.read_error or 'file ends without its footer'})"
            )
        if self.sent_not_finite:
            lines.append(
                f"{self.sent_not_finite} answer(s) logged as corrected hold a position that is "
                "not a finite number (a damaged log?): not compared"
            )
        return "; ".join(lines) or None

    def as_dict(self) -> dict[str, Any]:
        """JSON-friendly report."""
        out = {k: v for k, v in self.__dict__.items() if k != "diffs_um"}
        for k in ("max_abs_diff_um", "rms_diff_um", "max_abs_u_diff_um"):
            out[k] = None if not np.isfinite(out[k]) else float(out[k])
        return out


def _pair(messages: list[Any]) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Pair raw readings with the answers sent for them, by (source, seq) in order."""
    pending: dict[tuple[str, int], deque[dict[str, Any]]] = defaultdict(deque)
    raws: list[dict[str, Any]] = []
    sent: list[dict[str, Any]] = []
    for m in messages:
        if m.topic == "/cmm/raw":
            pending[(m.payload.get("source", ""), int(m.payload["seq"]))].append(m.payload)
        elif m.topic == "/cmm/corrected":
            key = (m.payload.get("source", ""), int(m.payload["seq"]))
            if pending[key]:
                raws.append(pending[key].popleft())
                sent.append(m.payload)
    return raws, sent


def _temperatures_at(temps: list[dict[str, Any]], stamps_ns: np.ndarray) -> dict[str, np.ndarray]:
    """Per role, the last usable sample at or before each stamp (NaN before the first)."""
    by_role: dict[str, list[tuple[int, float]]] = defaultdict(list)
    for t in temps:
        if t.get("valid", True) and not t.get("fault"):
            by_role[t["role"]].append((ns_from_stamp(t["stamp"]), float(t["temp_C"])))
    out: dict[str, np.ndarray] = {}
    for role, samples in by_role.items():
        samples.sort()
        t_ns = np.array([s[0] for s in samples], dtype=np.int64)
        v = np.array([s[1] for s in samples])
        idx = np.searchsorted(t_ns, stamps_ns, side="right") - 1
        out[role] = np.where(idx >= 0, v[np.clip(idx, 0, None)], np.nan)
    return out


def replay_offline(source: str | Path, grid_path: str | Path | None = None) -> ReplayReport:
    """Re-correct every reading of a session; see the module docstring."""
    try:
        res = read_messages(source)
    except FileNotFoundError as exc:
        raise ReplayError(str(exc)) from None
    grids = [m.payload for m in res.messages if m.topic == "/cmm/grid"]
    session_sha = grids[-1]["sha256"] if grids else ""
    if grid_path is None:
        if not grids:
            raise ReplayError(f"{source}: session logged no grid; pass --grid GRID")
        grid_path = grids[-1]["path"]
    try:
        grid = CorrectionGrid.load(grid_path)
    except (OSError, ValueError) as exc:
        raise ReplayError(f"{grid_path}: cannot load grid: {exc}") from None
    raws, sent = _pair(res.messages)
    n = len(raws)
    temps = [m.payload for m in res.messages if m.topic == "/cmm/temperature"]
    report = ReplayReport(
        session=[str(f) for f in res.files],
        truncated=res.truncated,
        grid_path=str(grid_path),
        grid_sha256=grid.sha256 or "",
        session_grid_sha256=session_sha,
        readings=n,
        compared=0,
        max_abs_diff_um=float("nan"),
        rms_diff_um=float("nan"),
        status_agree=0,
        read_error=res.error,
    )
    if n == 0:
        return report
    pts = np.array([[r["x_mm"], r["y_mm"], r["z_mm"]] for r in raws], dtype=float)
    stylus = np.array(
        [
            [r.get("stylus_x_mm", 0.0), r.get("stylus_y_mm", 0.0), r.get("stylus_z_mm", 0.0)]
            for r in raws
        ]
    )
    stamps = np.array([ns_from_stamp(r["stamp"]) for r in raws], dtype=np.int64)
    temps_C = {k: v for k, v in _temperatures_at(temps, stamps).items() if k in TEMPERATURE_ROLES}
    inputs: dict[str, np.ndarray] = {}
    travel = np.array([r.get("travel_dir", [0, 0, 0]) for r in raws], dtype=float)
    for k, key in enumerate(("dir_x", "dir_y", "dir_z")):
        col = travel[:, k]
        if np.any(col != 0):
            inputs[key] = np.where(col != 0, col, np.nan)
    corrected, status, u_replayed = grid.correct_with_uncertainty(
        pts, stylus, temps_C or None, inputs or None
    )
    sent_pos = np.array([[s["x_mm"], s["y_mm"], s["z_mm"]] for s in sent], dtype=float)
    sent_status = np.array([s["status"] for s in sent])
    replayed = np.array([_as_sent_label(s) for s in status])
    geometry = np.isin(sent_status, _GEOMETRY_APPLIED) & np.isin(replayed, _GEOMETRY_APPLIED)
    finite = np.all(np.isfinite(sent_pos), axis=1)
    report.sent_not_finite = int(np.sum(geometry & ~finite))
    both = geometry & finite
    diffs = (corrected[both] - sent_pos[both]) * 1000.0
    report.compared = int(both.sum())
    if report.compared:
        report.max_abs_diff_um = float(np.abs(diffs).max())
        report.rms_diff_um = float(np.sqrt(np.mean(np.sum(diffs**2, axis=1))))
    report.diffs_um = diffs
    agree = sent_status == replayed
    report.status_agree = int(agree.sum())
    for a, b in zip(sent_status[~agree], replayed[~agree], strict=True):
        key = f"{a}→{b}"
        report.status_differ[key] = report.status_differ.get(key, 0) + 1
    report.sent_statuses = _counts(sent_status)
    report.replayed_statuses = _counts(replayed)
    _compare_uncertainty(report, grid.has_uncertainty, sent, u_replayed)
    return report


def _compare_uncertainty(
    report: ReplayReport, grid_has_u: bool, sent: list[dict[str, Any]], u_replayed: np.ndarray
) -> None:
    """Fill the U fields of ``report``: the logged U (null or absent: unknown) against the
    replay's (NaN: unknown)."""
    u_sent = np.array(
        [[_u_value(s.get(k)) for k in ("ux_um", "uy_um", "uz_um")] for s in sent], dtype=float
    ).reshape(-1, 3)
    known_sent = np.all(np.isfinite(u_sent), axis=1)
    known_replayed = np.all(np.isfinite(u_replayed), axis=1)
    both = known_sent & known_replayed
    report.grid_has_uncertainty = grid_has_u
    report.sent_uncertainty_known = int(known_sent.sum())
    report.replayed_uncertainty_known = int(known_replayed.sum())
    report.uncertainty_compared = int(both.sum())
    report.uncertainty_mismatch = int((known_sent != known_replayed).sum())
    if report.uncertainty_compared:
        report.max_abs_u_diff_um = float(np.abs(u_replayed[both] - u_sent[both]).max())


def _u_value(value: Any) -> float:
    """A logged U component as a float: NaN for null, absent or anything not a number."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return float("nan")
    return float(value)


def _as_sent_label(grid_status: str) -> str:
    """The daemon's status label for a grid status (the engine's mapping; any other as it is)."""
    status = GRID_STATUS.get(str(grid_status))
    return str(grid_status) if status is None else status.label


def _counts(values: np.ndarray) -> dict[str, int]:
    keys, counts = np.unique(values, return_counts=True)
    return {str(k): int(c) for k, c in zip(keys, counts, strict=True)}


@dataclass
class BusReplayReport:
    """What :func:`replay_to_bus` sent and left out."""

    session: list[str]
    sent: int
    """Frames re-sent (the controller's)."""
    skipped_own: int
    """The daemon's own frames found in ``/cmm/can_rx`` (echoed back by the bus): not sent."""
    skipped_error_frames: int
    """Error frames: not sent."""
    by_direction: int
    """Frames sorted by their logged ``direction`` field."""
    by_can_id: int
    """Frames without a usable ``direction`` (a log written before it): sorted by CAN id
    ownership per the DBC (:func:`cmm_comp.protocol.can_ids.sent_by_daemon`)."""
    truncated: bool = False
    read_error: str | None = None

    @property
    def note(self) -> str | None:
        """One line when frames were sorted by CAN id (an older log), else None."""
        if not self.by_can_id:
            return None
        return (
            f"{self.by_can_id} frame(s) carry no direction (a log written before frames were "
            "tagged): the daemon's own recognised by CAN id (DBC transmitter Daemon: offsets "
            "0x8-0xD and 0xF of a node's 16-id block), the rest re-sent as the controller's"
        )


def _is_controller_frame(payload: dict[str, Any]) -> tuple[bool, bool]:
    """``(sent by the controller, decided by the logged direction)`` of one ``/cmm/can_rx``
    payload: its ``direction`` when it has a valid one, else CAN id ownership."""
    direction = payload.get("direction")
    if direction == "rx":
        return True, True
    if direction in ("tx", "tx_echo"):
        return False, True
    own = sent_by_daemon(int(payload["arbitration_id"]), bool(payload.get("is_extended")))
    return not own, False


def replay_to_bus(
    source: str | Path, bus: can.BusABC, speed: float = 1.0, max_frames: int | None = None
) -> BusReplayReport:
    """Re-send the frames the controller sent in the session on ``bus`` at ``speed`` × the
    recorded pace (0 = as fast as possible); never the daemon's own (module docstring)."""
    try:
        res = read_messages(source, ("/cmm/can_rx",))
    except FileNotFoundError as exc:
        raise ReplayError(str(exc)) from None
    report = BusReplayReport(
        session=[str(f) for f in res.files],
        sent=0,
        skipped_own=0,
        skipped_error_frames=0,
        by_direction=0,
        by_can_id=0,
        truncated=res.truncated,
        read_error=res.error,
    )
    frames = []
    for m in res.messages:
        if m.payload.get("is_error_frame"):
            report.skipped_error_frames += 1
            continue
        controller, by_direction = _is_controller_frame(m.payload)
        report.by_direction += by_direction
        report.by_can_id += not by_direction
        if controller:
            frames.append(m)
        else:
            report.skipped_own += 1
    if not frames:
        raise ReplayError(
            f"{source}: no frames from the controller in /cmm/can_rx "
            f"({report.skipped_own} of the daemon's own; was can.log_frames off?)"
        )
    t0_ns = frames[0].log_time_ns
    start = time.perf_counter()
    for m in frames[:max_frames]:
        if speed > 0:
            due = start + (m.log_time_ns - t0_ns) / 1e9 / speed
            while (left := due - time.perf_counter()) > 0:
                time.sleep(min(left, 0.001))
        p = m.payload
        bus.send(
            can.Message(
                arbitration_id=int(p["arbitration_id"]),
                is_extended_id=bool(p["is_extended"]),
                is_remote_frame=bool(p.get("is_remote_frame", False)),
                is_fd=bool(p.get("is_fd", False)),
                data=bytes.fromhex(p["data"]),
                dlc=int(p["dlc"]),
            ),
            timeout=1.0,
        )
        report.sent += 1
    return report
