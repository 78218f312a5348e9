"""The documentation of both TOML files comes from, or is checked against, the definitions the
files are validated with: docs/daemon.md's configuration reference is generated (and must be
current), and every key of the machine definitions is in docs/formats.md §1's tables with its
default and unit, while those tables name no key the definitions lack."""

from __future__ import annotations

import dataclasses
import re
import tomllib
from pathlib import Path
from typing import Any

import jsonschema
import pytest

from cmm_comp.cli.config_doc import BEGIN, END, reference_markdown
from cmm_comp.compensation.formats.machine_schema import (
    ArmDeflectionSection,
    ErrorTableSection,
    MachineFile,
    ProbeSection,
    SquarenessSection,
    ThermalSection,
    VolumeSection,
)
from cmm_comp.compensation.toml_schema import Num, Vec, adapter, rules_of
from cmm_comp.compensation.uncertainty.model import TableUncertaintySection, UncertaintySection
from cmm_comp.daemon.config import DaemonConfig

ROOT = Path(__file__).resolve().parents[1]
DAEMON_DOC = ROOT / "docs" / "daemon.md"
FORMATS_DOC = ROOT / "docs" / "formats.md"


def test_the_daemon_reference_is_generated_from_the_current_definitions() -> None:
    text = DAEMON_DOC.read_text(encoding="utf-8")
    block = text[text.index(BEGIN) : text.index(END) + len(END)]
    assert block == reference_markdown(), (
        "docs/daemon.md is stale: python -m cmm_comp.cli.config_doc docs/daemon.md"
    )


def test_the_daemon_reference_names_every_key_and_no_other() -> None:
    """Every ``| `key` |`` row of the reference under its ``[section]`` heading is a key of the
    definitions, and every key of the definitions has its row (type, default, allowed)."""
    text = DAEMON_DOC.read_text(encoding="utf-8")
    block = text[text.index(BEGIN) : text.index(END)]
    documented: dict[str, set[str]] = {}
    section = ""
    for line in block.splitlines():
        if m := re.match(r"\*\*`\[(\w+)\]`\*\*", line):
            section = m.group(1)
            documented[section] = set()
        elif m := re.match(r"\| `(\w+)` \| (\w[^|]*) \| `([^`]*)` \| ([^|]+) \|", line):
            documented[section].add(m.group(1))
    defaults = DaemonConfig()
    assert set(documented) == set(DaemonConfig.toml_keys())
    for name in DaemonConfig.toml_keys():
        cls = type(getattr(defaults, name))
        assert documented[name] == set(cls.toml_keys()), name  # type: ignore[attr-defined]


def test_the_example_configuration_is_valid_for_an_independent_validator() -> None:
    """pydantic's JSON Schema of the definitions, checked by ``jsonschema`` (another library):
    the shipped example passes; out-of-range values and unknown keys fail there too."""
    schema = adapter(DaemonConfig).json_schema()
    example = tomllib.loads((ROOT / "examples" / "daemon.toml").read_text(encoding="utf-8"))
    jsonschema.validate(example, schema)
    for bad in (
        {"modbus": {"port": 70000}},
        {"can": {"heartbeat_s": 0.0}},
        {"limits": {"warn": 1.0}},
        {"log": {"level": "loud"}},
        {"grid": {"stylus_mm": [0.0, 0.0]}},
    ):
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate(bad, schema)


# --------------------------------------------------------------------------- docs/formats.md §1
def _section(heading: str) -> str:
    """The text of the formats.md subsection whose heading contains ``heading``."""
    text = FORMATS_DOC.read_text(encoding="utf-8")
    start = text.index(heading)
    end = re.compile(r"^##", re.M).search(text, start + len(heading))
    return text[start : end.start() if end else len(text)]


def _rows(text: str) -> dict[str, str]:
    """First-column keys of the markdown tables in ``text`` (``x``, ``y``, ``z`` split) → row."""
    rows = {}
    column = 1
    for line in text.splitlines():
        if line.startswith("| source | keys |"):  # §1.7: the keys of each source, column 2
            column = 2
        elif line.startswith("| ours |"):  # §1.7: the component names, not keys
            column = 99
        elif not line.startswith("|"):
            column = 1
        cells = line.split("|")
        if not line.startswith("| ") or len(cells) <= column:
            continue
        pattern = r"`\[?([\w.<>]+)" if column == 2 else r"`\[?([\w.<>]+)\]?`"
        for key in re.findall(pattern, cells[column]):
            rows[key.removeprefix("uncertainty.").removeprefix(".")] = line
    return rows


def _numbers(value: Any) -> list[float]:
    if dataclasses.is_dataclass(value):
        return [float(v) for v in dataclasses.astuple(value)]  # type: ignore[arg-type]
    if isinstance(value, list):
        return [float(v) for v in value]
    return [float(value)]


def _unit(cls: type, key: str) -> str:
    for rule in rules_of(cls, key):
        unit = (
            rule.unit if isinstance(rule, Num) else rule.item.unit if isinstance(rule, Vec) else ""
        )
        if unit:
            return unit
    inner = getattr(cls, "__dataclass_fields__", {})[key].default_factory
    if callable(inner) and dataclasses.is_dataclass(inner):  # e.g. thermal.expansion
        units = {_unit(inner, f.name) for f in dataclasses.fields(inner)}
        return units.pop() if len(units) == 1 else ""
    return ""


SECTIONS = [
    ("### 1.3 `[volume]`", VolumeSection, ()),
    ("### 1.4 `[probe]`", ProbeSection, ()),
    ("### 1.5 `[thermal]`", ThermalSection, ()),
    ("### 1.6 `[squareness]`", SquarenessSection, ()),
    ("### 1.7 `[errors.*]`", ErrorTableSection, ("curve", "criterion")),
    ("### 1.8 `[arm_deflection]`", ArmDeflectionSection, ()),
    ("### 1.11 `[uncertainty]`", UncertaintySection, ()),
]


@pytest.mark.parametrize(("heading", "cls", "_"), SECTIONS, ids=[s[1].__name__ for s in SECTIONS])
def test_formats_doc_tables_match_the_machine_definitions(
    heading: str, cls: type, _: tuple[str, ...]
) -> None:
    """Each key has a row; a row's default (where the table has a default column) is the
    definition's and its unit is named; no row names a key the definition lacks."""
    text = _section(heading)
    rows = _rows(text)
    keys = set(cls.toml_keys())  # type: ignore[attr-defined]
    if cls is UncertaintySection:
        keys = keys - {"errors"} | {"errors.<name>"}
    assert keys <= set(rows), sorted(keys - set(rows))
    extra = set(rows) - keys
    if cls is UncertaintySection:  # the per-class table: its rows are classes, not keys
        extra -= {"dx_x", "dy_y", "dz_z"}
    assert not extra, sorted(extra)
    defaults = cls.__dataclass_fields__  # type: ignore[attr-defined]
    has_default_column = "| key | default |" in text
    for key in cls.toml_keys():  # type: ignore[attr-defined]
        row = rows[key if key != "errors" else "errors.<name>"]
        unit = _unit(cls, key)
        assert unit in row, (key, unit, row)
        spec = defaults[key]
        default = spec.default_factory() if callable(spec.default_factory) else spec.default
        if not has_default_column or default is None or default is dataclasses.MISSING:
            continue
        cell = row.split("|")[2]
        got = [float(v) for v in re.findall(r"-?\d+(?:\.\d+)?(?:e[-+]?\d+)?", cell)]
        want = _numbers(default)
        assert got == want or ("zero" in cell and not any(want)), (key, cell, want)


def test_formats_doc_names_every_top_level_key_and_table() -> None:
    text = _section("### 1.1 Top level")
    rows = _rows(text)
    scalars = {"format", "name", "model"}
    assert set(rows) == scalars
    assert '"cmm-machine/1"' in rows["format"]
    for key in set(MachineFile.toml_keys()) - scalars:
        assert re.search(rf"`\[+{key}(\.\*)?\]+`", text), key
    chain = _section("### 1.2 The kinematic models")
    assert "tool = [" in chain and "workpiece = [" in chain


def test_uncertainty_class_table_names_the_per_table_keys() -> None:
    text = _section("### 1.11 `[uncertainty]`")
    header = next(line for line in text.splitlines() if line.startswith("| class |"))
    for key in TableUncertaintySection.toml_keys():
        assert f"`{key}`" in header, key
