"""Cases, measurements and the naming rule of the independent discovery benchmark.

A case is (hidden causes, size, seed). (seed, label) draws the machine (model, volume, nominal
tables) and the session design, the same at every size; the effects' shapes are drawn from
(seed, cause) so the same shape is used at every size. Each effect is scaled so its 3-D RMS over the session's points is
``size × noise 3-D RMS``.

The measurements are ``ref = q + (nominal + hidden + noise)/1000`` with ``nominal`` the project's
``Machine.volumetric_error`` of the description the diagnosis is given (logged temperatures,
directions, normals) and ``hidden`` this package's own forward models.

Naming rule: a case is *named* when the set of identities the diagnosis names equals the hidden
set, where a hidden identity also matches a found entry when it is among that entry's
``alternatives`` (*strict*: the named identities themselves must equal the hidden set).
Identities are (cause, component, axis, varies_with) with None where a cause has no such key.
"""

from __future__ import annotations

import time
import zlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cmm_comp.compensation.formats.measurements import Measurements

from .chains import MODELS
from .effects import CAUSES, IDENT_KEYS, HiddenEffect, draw_effect, rms3d, scale_to
from .machines import MachineSpec, draw_machine
from .sessions import Design, Session, draw_session

Identity = tuple[str | None, ...]

SINGLE_CAUSES = CAUSES
PAIRS = (
    ("coupling", "periodic"),
    ("thermal_gradient", "scale_expansion"),
    ("reversal", "periodic"),
    ("parametric", "squareness_drift"),
    ("thermal_lag", "workpiece_expansion"),
    ("coupling", "probe_lobing"),
    ("drift", "reversal"),
    ("parametric", "coupling"),
    ("thermal_gradient", "parametric"),
    ("periodic", "drift"),
)


@dataclass
class Case:
    """One generated session with its truth."""

    label: str
    size: float
    seed: int
    spec: MachineSpec
    session: Session
    hidden: list[HiddenEffect]
    data: Measurements
    noise_rms_3d_um: float
    notes: dict[str, Any] = field(default_factory=dict)

    def hidden_identities(self) -> list[Identity]:
        return sorted((h.identity() for h in self.hidden), key=_key)


def _key(ident: Identity) -> tuple[str, ...]:
    return tuple("" if v is None else str(v) for v in ident)


def _stable(text: str) -> int:
    return zlib.crc32(text.encode())


def build_case(
    label: str,
    size: float,
    seed: int,
    *,
    model: str | None = None,
    design: Design | None = None,
) -> Case:
    """Generate case ``label`` (``"none"``, a cause, or ``"a+b"``) at ``size`` × noise, ``seed``."""
    # machine and design from (seed, label): every cause meets several models and designs; the
    # model is stratified so that consecutive seeds of one label walk through all ten
    rng = np.random.default_rng([seed, _stable(label), 7])
    if model is None:
        model = sorted(MODELS)[(seed + _stable(label)) % len(MODELS)]
    spec = draw_machine(rng, model)
    session = draw_session(rng, spec, design)
    causes = [] if label == "none" else label.split("+")
    hidden: list[HiddenEffect] = []
    target = size * session.noise_rms_3d_um
    for cause in causes:
        erng = np.random.default_rng([seed, _stable(cause), 11])
        for _ in range(20):
            effect = draw_effect(cause, erng, spec, session)
            if all(effect.identity() != h.identity() for h in hidden):
                break
        hidden.append(scale_to(effect, target))
    machine = spec.machine()
    inputs: dict[str, Any] = dict(session.directions)
    inputs["t"] = session.t_s
    for k, c in enumerate(("nx", "ny", "nz")):
        inputs[c] = session.normals[:, k]
    nominal = machine.volumetric_error(
        session.q_mm, stylus_mm=session.stylus_mm, temps_C=session.temps_C, inputs=inputs
    )
    hidden_um = sum((h.error_um() for h in hidden), np.zeros_like(nominal))
    nrng = np.random.default_rng([seed, 13])
    noise = nrng.normal(0.0, session.design.noise_um, nominal.shape)
    truth_um = nominal + hidden_um + noise
    data = Measurements(
        indicated_mm=session.q_mm.copy(),
        reference_mm=session.q_mm + truth_um / 1000.0,
        t_s=session.t_s.copy(),
        temps_C={k: v.copy() for k, v in session.temps_C.items()},
        directions={k: v.copy() for k, v in session.directions.items()},
        normals=session.normals.copy(),
        stylus_mm=session.stylus_mm.copy(),
        group=session.group.copy(),
        source=f"<independent {label} size={size} seed={seed}>",
    )
    return Case(
        label=label,
        size=size,
        seed=seed,
        spec=spec,
        session=session,
        hidden=hidden,
        data=data,
        noise_rms_3d_um=session.noise_rms_3d_um,
        notes={
            "model": spec.model,
            "design": session.design.label,
            "n_points": session.n,
            "hidden_rms_um": rms3d(hidden_um) if hidden else 0.0,
            "temperatures_C": _temperature_notes(session, spec.reference_C),
        },
    )


def _temperature_notes(session: Session, reference_C: float) -> dict[str, list[float]]:
    """Per signal (and T_top − T_bottom): [mean − reference, peak-to-peak] over the session, °C.
    A thermal cause whose driving signal hardly moves is, in this session, a table change."""
    sig = dict(session.temps_C)
    sig["dT_top_bottom"] = sig["T_top"] - sig["T_bottom"] + reference_C
    return {
        k: [round(float(np.mean(v) - reference_C), 3), round(float(np.ptp(v)), 3)]
        for k, v in sig.items()
    }


def identity_of(entry: dict[str, Any]) -> Identity:
    """(cause, component, axis, varies_with) of a diagnosis entry or alternative."""
    return tuple(entry.get(k) for k in IDENT_KEYS)


def judge(
    hidden: list[Identity],
    entries: list[dict[str, Any]],
    equivalents: list[list[Identity]] | None = None,
) -> dict[str, bool]:
    """``named`` (alternatives accepted), ``strict`` (named identities only) and ``equivalent``
    (named, or named as an identity that acts exactly like the hidden one on this session).

    Named: there is a one-to-one matching between found entries and hidden identities in which
    each pair matches by the entry's identity or one of its ``alternatives``.
    """
    found = [identity_of(e) for e in entries]
    strict = sorted(found, key=_key) == sorted(hidden, key=_key)
    if len(found) != len(hidden):
        return {"named": False, "strict": False, "equivalent": False}
    options = [
        {identity_of(e), *(identity_of(a) for a in e.get("alternatives", []) or [])}
        for e in entries
    ]
    equivalents = equivalents or [[] for _ in hidden]
    hidden_sets = [{h, *eq} for h, eq in zip(hidden, equivalents, strict=True)]

    def match(i: int, left: list[int], loose: bool) -> bool:
        if i == len(options):
            return not left
        for j, h in enumerate(left):
            ok = bool(options[i] & hidden_sets[h]) if loose else hidden[h] in options[i]
            if ok and match(i + 1, left[:j] + left[j + 1 :], loose):
                return True
        return False

    named = strict or match(0, list(range(len(hidden))), False)
    return {
        "named": named,
        "strict": strict,
        "equivalent": named or match(0, list(range(len(hidden))), True),
    }


def run_case(label: str, size: float, seed: int, **kwargs: Any) -> dict[str, Any]:
    """Generate, diagnose and judge one case; a JSON-ready record."""
    from cmm_comp.compensation.diagnosis import diagnose

    case = build_case(label, size, seed, **kwargs)
    machine = case.spec.machine()
    t0 = time.perf_counter()
    d = diagnose(machine, case.data)
    elapsed = time.perf_counter() - t0
    entries = [dict(e) for e in d.entries]
    hidden_effects = sorted(case.hidden, key=lambda h: _key(h.identity()))
    hidden = [h.identity() for h in hidden_effects]
    verdict = judge(hidden, entries, [h.equivalent for h in hidden_effects])
    heldout = float(d.summary["heldout_rms_um"]["after"])
    return {
        "case": label,
        "size": size,
        "seed": seed,
        "named": verdict["named"],
        "strict": verdict["strict"],
        "equivalent": verdict["equivalent"],
        "hidden": [list(h) for h in hidden],
        "hidden_detail": [h.describe() for h in hidden_effects],
        "found": [list(identity_of(e)) for e in entries],
        "alternatives": [
            [list(identity_of(a)) for a in e.get("alternatives", []) or []] for e in entries
        ],
        "heldout_rms_um": heldout,
        "noise_rms_3d_um": case.noise_rms_3d_um,
        "heldout_ok": heldout <= 1.5 * case.noise_rms_3d_um,
        "seconds": elapsed,
        **case.notes,
    }
