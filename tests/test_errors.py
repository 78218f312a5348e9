"""Every exception class the project defines derives from ``CmmCompError`` (issue 10), and the
input errors stay ``ValueError`` so existing ``except ValueError`` callers keep working."""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import pytest

from cmm_comp.compensation import errors
from cmm_comp.compensation.errors import CmmCompError

# ``cmm_comp.compensation.errors`` imports nothing heavy (the package __init__s are lazy), so
# the protocol's client errors derive from CmmCompError too.
PACKAGES = (
    "cmm_comp.compensation",
    "cmm_comp.protocol",
    "cmm_comp.daemon",
    "cmm_comp.sim_controller",
    "cmm_comp.cli",
)


def _project_exceptions() -> dict[str, type[BaseException]]:
    found: dict[str, type[BaseException]] = {}
    for package_name in PACKAGES:
        package = importlib.import_module(package_name)
        names = [package_name] + [
            info.name
            for info in pkgutil.walk_packages(package.__path__, prefix=f"{package_name}.")
            if not info.name.endswith("__main__")  # runs the CLI
        ]
        for name in names:
            module = importlib.import_module(name)
            for obj in vars(module).values():
                if (
                    inspect.isclass(obj)
                    and issubclass(obj, BaseException)
                    and obj.__module__ == module.__name__
                ):
                    found[f"{obj.__module__}.{obj.__qualname__}"] = obj
    return found


def test_every_project_exception_derives_from_cmm_comp_error() -> None:
    found = _project_exceptions()
    # the walk sees the exceptions issue 10 names (so an empty walk cannot pass)
    short = {qualified.rsplit(".", 1)[1] for qualified in found}
    assert {
        "RealDataError",
        "GridFileError",
        "ConfigError",
        "GridLoadError",
        "ReplayError",
        "ModbusExceptionError",
        "AnswerTimeoutError",
    } <= short
    assert sorted(q for q, cls in found.items() if not issubclass(cls, CmmCompError)) == []


def test_compensation_errors_live_in_errors_module() -> None:
    found = _project_exceptions()
    for qualified in found:
        if qualified.startswith("cmm_comp.compensation."):
            assert qualified.startswith("cmm_comp.compensation.errors."), qualified


@pytest.mark.parametrize(
    "name", ["MachineFileError", "MeasurementFileError", "GridFileError", "RealDataError"]
)
def test_input_errors_are_still_value_errors(name: str) -> None:
    cls = getattr(errors, name)
    assert issubclass(cls, CmmCompError) and issubclass(cls, ValueError)


def test_daemon_input_errors_are_still_value_errors() -> None:
    from cmm_comp.daemon.config import ConfigError
    from cmm_comp.daemon.grid_slot import GridLoadError

    for cls in (ConfigError, GridLoadError):
        assert issubclass(cls, CmmCompError) and issubclass(cls, ValueError)


def test_public_names_are_the_errors_module_classes() -> None:
    import cmm_comp.compensation as comp
    from cmm_comp.compensation.formats import realdata

    assert comp.GridFileError is errors.GridFileError
    assert comp.RealDataError is errors.RealDataError
    assert realdata.RealDataError is errors.RealDataError
