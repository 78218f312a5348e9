"""An import-linter contract type the built-in ones cannot express (pyproject.toml
``[tool.importlinter]``; ``lint-imports`` imports this module from the repository's root).

``relative_imports_in_package``: a relative import (``from .x``, ``from ..x``) never leaves the
top-level package it is written in. ``cmm_comp`` is a namespace, so ``from ... import protocol``
inside ``cmm_comp.daemon.live`` does import ``cmm_comp.protocol``; the layers contract judges
where it points, this one that it is spelled ``cmm_comp.protocol`` (one place to read and grep
for what a package uses of another).
"""

from __future__ import annotations

from typing import Any

from importlinter import Contract, ContractCheck, fields, output


class RelativeImportsInPackageContract(Contract):
    type_name = "relative_imports_in_package"

    packages = fields.ListField(subfield=fields.StringField())
    """The top-level packages: a relative import must resolve inside the one it is written in."""

    def _package_of(self, module: str) -> str | None:
        for package in self.packages:  # type: ignore[attr-defined]
            if module == package or module.startswith(package + "."):
                return str(package)
        return None

    def check(self, graph: Any, verbose: bool) -> ContractCheck:
        bad: list[dict[str, object]] = []
        for importer in sorted(graph.modules):
            own = self._package_of(importer)
            if own is None:
                continue
            for imported in sorted(graph.find_modules_directly_imported_by(importer)):
                if self._package_of(imported) in (None, own):
                    continue
                for detail in graph.get_import_details(importer=importer, imported=imported):
                    if str(detail["line_contents"]).lstrip().startswith("from ."):
                        bad.append({"importer": importer, "imported": imported, **detail})
        return ContractCheck(kept=not bad, warnings=None, metadata={"bad": bad})

    def render_broken_contract(self, check: ContractCheck) -> None:
        for b in check.metadata["bad"]:
            output.print_error(
                f"{b['importer']}:{b['line_number']}: {b['line_contents']} "
                f"(a relative import of {b['imported']}; write it absolute)"
            )
            output.new_line()
