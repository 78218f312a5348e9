"""The ten kinematic models of the paper: codes, readable aliases and one-line descriptions.

``machine.toml`` accepts either (``model = "MB1"`` or ``model = "moving_bridge"``); a loaded
:class:`~.machine.Machine` always keeps the code (``machine.model == "MB1"``). The chains
themselves are :data:`.kinematics.MODEL_CHAINS`; docs/seed-equations.md lists them with the
paper's equations.

====  ======================  ==========================================================
code  alias                   structure
====  ======================  ==========================================================
MB1   moving_bridge           bridge travels in Y, carriage X on it, ram Z
MB2   moving_bridge_x         bridge travels in X, carriage Y on it, ram Z
FB1   fixed_bridge            carriage X on a fixed bridge, ram Z; table moves in Y
FB2   fixed_bridge_x          carriage Y on a fixed bridge, ram Z; table moves in X
MH1   horizontal_arm          column travels in Y, carriage Z up it, arm X through it
MH2   horizontal_arm_y        column travels in X, carriage Z up it, arm Y through it
FH1   fixed_horizontal_arm    column travels in Y with carriage Z; table moves in X
FH2   fixed_horizontal_arm_y  column travels in X with carriage Z; table moves in Y
CX1   column                  vertical ram Z; two-axis table, X lower, Y upper
CY1   column_y                vertical ram Z; two-axis table, Y lower, X upper
====  ======================  ==========================================================
"""

from __future__ import annotations

__all__ = ["MODEL_ALIASES", "describe_model", "known_models", "model_code", "model_table"]

#: model code → (readable alias, structure in one line)
_MODELS: dict[str, tuple[str, str]] = {
    "MB1": ("moving_bridge", "moving bridge: bridge travels in Y, carriage X on it, ram Z"),
    "MB2": ("moving_bridge_x", "moving bridge: bridge travels in X, carriage Y on it, ram Z"),
    "FB1": ("fixed_bridge", "fixed bridge: carriage X on the bridge, ram Z; table moves in Y"),
    "FB2": ("fixed_bridge_x", "fixed bridge: carriage Y on the bridge, ram Z; table moves in X"),
    "MH1": (
        "horizontal_arm",
        "moving horizontal arm: column travels in Y, carriage Z, arm X through the carriage",
    ),
    "MH2": (
        "horizontal_arm_y",
        "moving horizontal arm: column travels in X, carriage Z, arm Y through the carriage",
    ),
    "FH1": (
        "fixed_horizontal_arm",
        "fixed horizontal arm: column travels in Y with carriage Z; table moves in X",
    ),
    "FH2": (
        "fixed_horizontal_arm_y",
        "fixed horizontal arm: column travels in X with carriage Z; table moves in Y",
    ),
    "CX1": ("column", "column type: vertical ram Z; two-axis table, X lower, Y upper"),
    "CY1": ("column_y", "column type: vertical ram Z; two-axis table, Y lower, X upper"),
}
# tests/test_machine_api.py checks that these are exactly the codes of kinematics.MODEL_CHAINS
# (not imported here: the CLI's --help reads this table without numpy)

#: readable alias → model code (``"moving_bridge"`` → ``"MB1"``)
MODEL_ALIASES: dict[str, str] = {alias: code for code, (alias, _) in _MODELS.items()}


def model_code(name: str) -> str | None:
    """The model code (``"MB1"``) for a code or an alias (case, ``-`` and spaces ignored in
    aliases), or None when ``name`` names none of the ten models."""
    if name in _MODELS:
        return name
    key = name.strip().lower().replace("-", "_").replace(" ", "_")
    if key.upper() in _MODELS:
        return key.upper()
    return MODEL_ALIASES.get(key)


def describe_model(name: str) -> str:
    """One line for model ``name`` (code or alias): code, alias, structure and chain.

    ``describe_model("MB1")`` → ``"MB1 (moving_bridge): moving bridge: bridge travels in Y, …"``.
    ValueError naming the known models when ``name`` is none of them.
    """
    code = model_code(name)
    if code is None:
        raise ValueError(f"unknown model {name!r}; known: {', '.join(_known())}")
    from .kinematics import MODEL_CHAINS

    alias, text = _MODELS[code]
    return f"{code} ({alias}): {text}; {MODEL_CHAINS[code].describe()}"


def model_table() -> str:
    """The ten models, one line each: code, alias, structure (for ``cmm-comp --help``)."""
    width = max(len(alias) for alias, _ in _MODELS.values())
    return "\n".join(f"{code}  {alias:<{width}}  {text}" for code, (alias, text) in _MODELS.items())


def _known() -> list[str]:
    return [f"{code}/{alias}" for code, (alias, _) in _MODELS.items()]


def known_models() -> str:
    """``"MB1/moving_bridge, MB2/moving_bridge_x, …"``: for error messages."""
    return ", ".join(_known())
