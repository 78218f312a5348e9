"""Independent readers of the three controller formats, written from the public documentation
(not from cmm-comp's writers), and evaluators that apply a file exactly as the control does.

* SINUMERIK CEC — applied as the passages quoted in docs/export.md ("SINUMERIK: what the manuals
  say") describe, and nothing else (Function Manual Extended Functions 6FC5397-1BP40-3BA1, K3;
  802D sl 6FC5397-1CP10-5BA0):
  [T] ``$AN_CEC[t,N]`` is "the compensation value of the compensation axis" at interpolation point
      N; point 0 at ``$AN_CEC_MIN[t]``, spacing ``$AN_CEC_STEP[t]``, the last at ``$AN_CEC_MAX[t]``;
      "The compensation value of interpolation point 0 is used for all positions smaller than the
      initial position", that of point k "for all positions larger than the end position" (p. 248);
      between points "linear interpolation" (p. 237);
  [I] the input is "the setpoint" of ``$AN_CEC_INPUT_AXIS`` (p. 248; 802D: "The programmed
      (required) position setpoint is always used", p. 215), the output axis ``$AN_CEC_OUTPUT_AXIS``;
  [D] ``$AN_CEC_DIRECTION`` 0 both, 1 "only the positive", −1 "only the negative traversing
      direction of the basic axis" (p. 249);
  [S] "The total compensation value is derived from the sum of the individual compensation values"
      (802D p. 215);
  [M] ``$AN_CEC_MULT_BY_TABLE[t] = m``: "the compensation values of any table can be multiplied by
      those of any other table … The product is added as an additional compensation value to the
      total compensation value" (p. 249), read as in the only worked example (p. 252, foundation
      sag: ΔX1 = Z1·sinβ(X1), table 1 = sinβ(X1) with ``$AN_CEC_MULT_BY_TABLE[0] = 2``, table 2 =
      Z1): the referenced table enters as the factor only — table 2 holds Z1 itself, hundreds of
      mm, which cannot also move X1 — and the referencing table's own value stays in the sum;
      ``referencing_own=False`` leaves the latter out (the example cannot tell: sinβ ≈ 0). Products
      the passages do not describe (chains, a table times itself, products with a direction)
      are refused;
  [±] the sign: "A positive compensation value causes the corresponding machine axis to move in
      the negative direction" (MSEC, p. 238), the compensation curve drawn on the error curve
      (Figure 4-4, p. 237): the output axis moves by minus the total, so the error (true −
      indicated) taken off is ``+1000·total`` µm. ``sign=-1`` applies the opposite reading.
* TwinCAT CNC (TF5200 axis compensation, P-COMP-00001…25): ``kopf.achs_nr`` logical axis,
  ``kw.ssfk.*`` leadscrew table with ``unit`` 1 = lengths in 0.1 µm, ``interval`` spacing
  (0 = ``table[i].setpoint`` given), ``kw_startpos``, ``kw_nr_max`` points, ``bilateral``,
  ``table[i].pos``/``.neg`` = Δs = actual − set (the manual's worked example); ``kw.crosscomp.*``
  in the slave axis' list: ``master_ax_nr``, ``last_index``, ``table[i].setpoint`` ascending,
  ``table[i].correction``; linear interpolation between points. Beyond the ends the pages say
  nothing: the evaluator refuses positions outside a table.
* LinuxCNC (INI configuration, ``[JOINT_n] COMP_FILE``/``COMP_FILE_TYPE``): triplets ``nominal
  forward reverse``, nominals ascending, ≤ 256 per joint; type 0 forward/reverse are the actual
  positions when commanded to the nominal moving up/down, type 1 the offsets (trims); values
  interpolated between nominals; the trim is added to the command (type 0: trim = nominal −
  actual), so the error taken off is ``−trim``; beyond the ends the end trims hold (motion module).

Each ``*_error_um`` returns the error (N, 3) µm the file takes off at commanded positions ``q``
(N, 3) mm with travel directions ``dirs`` (N, 3) ±1; residual = model error − that.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

_CEC_VALUE = re.compile(r"^\$AN_CEC\[(\d+),(\d+)\]=(\S+)$")
_CEC_PARAM = re.compile(r"^\$AN_CEC_([A-Z_]+)\[(\d+)\]=(\S+)$")


def _interp_clamped(x: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """Linear interpolation written out by hand; end values held outside [xp0, xpn]."""
    out = np.empty(len(x))
    for n, v in enumerate(x):
        if v <= xp[0]:
            out[n] = fp[0]
        elif v >= xp[-1]:
            out[n] = fp[-1]
        else:
            i = int(np.searchsorted(xp, v, side="right")) - 1
            t = (v - xp[i]) / (xp[i + 1] - xp[i])
            out[n] = fp[i] + t * (fp[i + 1] - fp[i])
    return out


# ----------------------------------------------------------------------------- SINUMERIK CEC
@dataclass
class CecTableRead:
    values: dict[int, float] = field(default_factory=dict)
    params: dict[str, str] = field(default_factory=dict)

    def positions(self) -> np.ndarray:
        lo, step = float(self.params["MIN"]), float(self.params["STEP"])
        return lo + step * np.arange(len(self.values))


def read_cec(text: str) -> dict[int, CecTableRead]:
    lines = [ln.strip() for ln in text.splitlines()]
    assert lines[0] == "%_N_NC_CEC_INI", lines[0]
    assert lines[-1] == "M17"
    tables: dict[int, CecTableRead] = {}
    for ln in lines[1:-1]:
        if not ln or ln.startswith(";") or ln == "CHANDATA(1)":
            continue
        m = _CEC_VALUE.match(ln)
        if m:
            tables.setdefault(int(m[1]), CecTableRead()).values[int(m[2])] = float(m[3])
            continue
        m = _CEC_PARAM.match(ln)
        assert m, f"not a CEC line: {ln!r}"
        tables.setdefault(int(m[2]), CecTableRead()).params[m[1]] = m[3]
    for t, tab in tables.items():
        lo, hi, step = (float(tab.params[k]) for k in ("MIN", "MAX", "STEP"))
        k = (hi - lo) / step
        assert step > 0 and abs(k - round(k)) < 1e-9, (t, lo, hi, step)
        assert sorted(tab.values) == list(range(round(k) + 1)), f"table {t}: points 0…{round(k)}"
        assert tab.params["DIRECTION"] in ("0", "1", "-1")
        assert tab.params["IS_MODULO"] == "0"
    return tables


def _cec_table_value(
    tab: CecTableRead, axis_of: dict[str, int], q: np.ndarray, dirs: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """[T], [I], [D]: the table's value at the input axis' commanded positions, and where the
    table applies (its direction)."""
    a = axis_of[tab.params["INPUT_AXIS"]]
    vals = np.array([tab.values[n] for n in range(len(tab.values))])
    v = _interp_clamped(q[:, a], tab.positions(), vals)
    d = int(tab.params["DIRECTION"])
    applies = np.ones(len(q), bool) if d == 0 else (np.sign(dirs[:, a]) == d)
    return v, applies


def cec_error_um(
    tables: dict[int, CecTableRead],
    axis_names: list[str],
    q: np.ndarray,
    dirs: np.ndarray,
    *,
    referencing_own: bool = True,
    sign: int = 1,
) -> np.ndarray:
    """The error (N, 3) µm the tables take off at commanded positions ``q`` with travel
    directions ``dirs``: [S] the sum per output axis, [M] products, [±] the sign."""
    axis_of = {f"({name})": i for i, name in enumerate(axis_names)}
    referenced = {int(t.params["MULT_BY_TABLE"]) - 1 for t in tables.values()} - {-1}
    total = np.zeros((len(q), 3))
    for t, tab in tables.items():
        k = axis_of[tab.params["OUTPUT_AXIS"]]
        v, applies = _cec_table_value(tab, axis_of, q, dirs)
        m = int(tab.params["MULT_BY_TABLE"]) - 1
        if m >= 0:
            other = tables[m]
            assert m != t, f"table {t} times itself: not in the passages"
            assert m not in referenced or int(other.params["MULT_BY_TABLE"]) == 0, "a chain"
            assert t not in referenced, f"table {t} is both factor and product: not described"
            assert tab.params["DIRECTION"] == other.params["DIRECTION"] == "0", "product+direction"
            assert axis_of[other.params["OUTPUT_AXIS"]] == k, "[M] both tables of the output axis"
            w, _ = _cec_table_value(other, axis_of, q, dirs)
            total[:, k] += v * w
            if referencing_own:
                total[:, k] += v
        elif t not in referenced:
            total[:, k] += np.where(applies, v, 0.0)
    return sign * 1000.0 * total


# ----------------------------------------------------------------------------- TwinCAT CNC
def read_twincat(text: str) -> dict[str, str]:
    out: dict[str, str] = {}
    for raw in text.splitlines():
        ln = re.sub(r"/\*.*?\*/", "", raw).strip()
        if not ln or ln.startswith("#"):
            continue
        name, value = ln.split(None, 1)
        assert name not in out, f"{name} twice"
        out[name] = value.strip()
    return out


@dataclass
class TwinCatAxis:
    axis_nr: int
    ssfk_pos: np.ndarray  # positions mm
    ssfk_plus: np.ndarray  # values 0.1 µm
    ssfk_minus: np.ndarray
    master_nr: int | None = None
    cross_pos: np.ndarray | None = None
    cross_val: np.ndarray | None = None


def twincat_axis(entries: dict[str, str]) -> TwinCatAxis:
    nr = int(entries["kopf.achs_nr"])
    assert entries["kw.ssfk.unit"] == "1"
    n = int(entries["kw.ssfk.kw_nr_max"])
    assert n < int(entries.get("kw.ssfk.max_points", "1500"))
    interval = int(entries["kw.ssfk.interval"])
    if interval > 0:
        pos = (int(entries["kw.ssfk.kw_startpos"]) + interval * np.arange(n)) / 1e4
    else:
        pos = np.array([int(entries[f"kw.ssfk.table[{i}].setpoint"]) for i in range(n)]) / 1e4
    plus = np.array([int(entries[f"kw.ssfk.table[{i}].pos"]) for i in range(n)], float)
    if entries["kw.ssfk.bilateral"] == "1":
        minus = np.array([int(entries[f"kw.ssfk.table[{i}].neg"]) for i in range(n)], float)
    else:
        minus = plus
    axis = TwinCatAxis(nr, pos, plus, minus)
    if "kw.crosscomp.master_ax_nr" in entries:
        assert entries["kw.crosscomp.unit"] == "1"
        last = int(entries["kw.crosscomp.last_index"])
        assert last < int(entries.get("kw.crosscomp.max_points", "1001"))
        axis.master_nr = int(entries["kw.crosscomp.master_ax_nr"])
        axis.cross_pos = (
            np.array([int(entries[f"kw.crosscomp.table[{i}].setpoint"]) for i in range(last + 1)])
            / 1e4
        )
        assert np.all(np.diff(axis.cross_pos) > 0), "setpoints must ascend"
        axis.cross_val = np.array(
            [int(entries[f"kw.crosscomp.table[{i}].correction"]) for i in range(last + 1)], float
        )
    return axis


def twincat_error_um(
    axes: list[TwinCatAxis],
    axis_numbers: list[int],
    q: np.ndarray,
    dirs: np.ndarray,
    cross_sign: int = 1,
) -> np.ndarray:
    """``cross_sign`` +1: a cross ``correction`` is taken off like a leadscrew value (not stated
    by the pages: docs/export.md, "Not verified"); −1: added."""
    col = {nr: i for i, nr in enumerate(axis_numbers)}
    out = np.zeros((len(q), 3))
    for ax in axes:
        k = col[ax.axis_nr]
        x = q[:, k]
        assert x.min() >= ax.ssfk_pos[0] - 1e-9 and x.max() <= ax.ssfk_pos[-1] + 1e-9
        up = _interp_clamped(x, ax.ssfk_pos, ax.ssfk_plus)
        down = _interp_clamped(x, ax.ssfk_pos, ax.ssfk_minus)
        out[:, k] += np.where(dirs[:, k] > 0, up, down) / 10.0
        if ax.master_nr is not None:
            assert ax.cross_pos is not None and ax.cross_val is not None
            xm = q[:, col[ax.master_nr]]
            assert xm.min() >= ax.cross_pos[0] - 1e-9 and xm.max() <= ax.cross_pos[-1] + 1e-9
            out[:, k] += cross_sign * _interp_clamped(xm, ax.cross_pos, ax.cross_val) / 10.0
    return out


# ----------------------------------------------------------------------------- LinuxCNC
def read_linuxcnc(text: str) -> np.ndarray:
    rows = []
    for ln in text.splitlines():
        parts = ln.split()
        assert len(parts) == 3, f"not a triplet: {ln!r}"
        rows.append([float(p) for p in parts])
    arr = np.array(rows)
    assert 1 <= len(arr) <= 256
    assert np.all(np.diff(arr[:, 0]) > 0), "nominals must ascend"
    return arr


def linuxcnc_error_um(
    triplets: list[np.ndarray], file_type: int, q: np.ndarray, dirs: np.ndarray
) -> np.ndarray:
    out = np.zeros((len(q), 3))
    for k, arr in enumerate(triplets):
        nom = arr[:, 0]
        if file_type == 0:
            fwd_trim, rev_trim = nom - arr[:, 1], nom - arr[:, 2]
        else:
            fwd_trim, rev_trim = arr[:, 1], arr[:, 2]
        up = _interp_clamped(q[:, k], nom, fwd_trim)
        down = _interp_clamped(q[:, k], nom, rev_trim)
        out[:, k] = -1000.0 * np.where(dirs[:, k] > 0, up, down)
    return out
