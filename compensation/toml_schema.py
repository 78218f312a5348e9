"""The rules of the project's TOML files (the machine description, the daemon configuration),
declared once beside each key and checked by pydantic, which reports every problem at once.

A file's layout is a tree of dataclasses deriving from :class:`Table`; each field's type carries
its rule as ``Annotated`` metadata:

* :class:`Num` — a finite number within ``lo .. hi`` (a unit for the messages and docs); an
  ``int`` field takes integers only, a ``float`` field any number (integers become floats);
* :class:`Vec` — a list of such numbers (exactly ``n``, or at most ``max_n``);
* :class:`Choice` — one of a few strings;
* :class:`Rule` — any further check of one value (``check(value)`` yields the problems);
* :class:`Spread` — one number standing for every key of a table of numbers.

A :class:`Table` lists its cross-key rules in :meth:`Table.rules` (run once its keys are valid)
and refuses unknown keys, naming the allowed ones. Every scalar is strict: ``1`` is not
``true``, ``8765.0`` not an integer, ``"5"`` not a number. :func:`validate` returns the checked
object or raises :class:`SchemaError`, one line per problem: ``<file>: <key path> …``, e.g.
``d.toml: can.bitrate: 'fast' must be an integer`` or
``m.toml: volume.x[1] = 1e+300; allowed: -1e+06 .. 1e+06 mm``.

The definitions import nothing heavy (the CLI builds its parser from them): pydantic is imported
when a file is first validated.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar, get_args

from .errors import SchemaError

if TYPE_CHECKING:
    from pydantic import TypeAdapter, ValidationError
    from pydantic_core import InitErrorDetails

__all__ = [
    "Choice",
    "Num",
    "Problem",
    "Rule",
    "SchemaError",
    "Spread",
    "Table",
    "Vec",
    "usable",
    "validate",
]

PROBLEM = "cmm_problem"
"""The pydantic error type of every problem worded here (its context holds the text)."""

Problem = str | tuple[tuple[str | int, ...], str]
"""A problem a rule finds: its text, or ``(key path below the value, text)``. The text follows
the key path (``"must be [low, high]"`` → ``key: must be [low, high]``; a text starting with a
space is appended as it is: ``" = 3; allowed: …"``); ``{path}`` in it stands for the key path."""

_TYPE_WORDS = {
    "bool_type": "true or false",
    "string_type": "a string",
    "list_type": "a list",
    "dict_type": "a table",
    "int_type": "an integer",
    "float_type": "a number",
}


def shown(value: Any) -> str:
    """A value as the messages show it: floats as Python writes them (``nan``, ``1e+300``),
    lists element by element, anything else by ``str`` (strings by ``repr``)."""
    if isinstance(value, list | tuple):
        return "[" + ", ".join(shown(v) for v in value) + "]"
    if isinstance(value, float | str):
        return repr(value)
    return str(value)


def _num(value: float | None) -> str:
    return str(value) if isinstance(value, int) else f"{value:g}"


def short(value: Any, limit: int = 60) -> str:
    """``repr(value)`` cut to ``limit`` characters (a flag or a table may be any length)."""
    text = repr(value)
    return text if len(text) <= limit else f"{text[: limit - 1]}…"


def _problem(text: str, loc: tuple[str | int, ...] = (), value: Any = None) -> InitErrorDetails:
    from pydantic_core import PydanticCustomError

    return {
        "type": PydanticCustomError(PROBLEM, "{text}", {"text": text}),
        "loc": loc,
        "input": value,
    }


def _raise(details: list[InitErrorDetails], title: str = "value") -> None:
    from pydantic import ValidationError

    raise ValidationError.from_exception_data(title, details)


def _details(exc: ValidationError) -> list[InitErrorDetails]:
    """The errors of ``exc`` as details to raise again (with more, from an enclosing check)."""
    from pydantic_core import PydanticCustomError

    out: list[InitErrorDetails] = []
    for err in exc.errors(include_url=False):
        ctx = err.get("ctx")
        kind: Any = err["type"]
        if kind == PROBLEM:
            kind = PydanticCustomError(PROBLEM, "{text}", ctx)
        detail: InitErrorDetails = {"type": kind, "loc": err["loc"], "input": err["input"]}
        if ctx is not None and kind is err["type"]:
            detail["ctx"] = ctx
        out.append(detail)
    return out


# ------------------------------------------------------------------------------------ rules
@dataclass(frozen=True)
class Num:
    """A finite number in ``lo .. hi`` (``lo_open``: ``> lo``), in ``unit``; ``note`` is added to
    the allowed range in messages (``"0 = never"``). No bounds: any finite number."""

    lo: float | None = None
    hi: float | None = None
    unit: str = ""
    lo_open: bool = False
    note: str = ""

    def describe(self) -> str:
        """``> 0 and <= 60 s`` / ``0 .. 65535`` / ``a finite number``."""
        lo, hi = self.lo, self.hi
        if lo is None and hi is None:
            text = "a finite number"
        elif hi is None:
            text = f"{'>' if self.lo_open else '>='} {_num(lo)}"
        elif lo is None:
            text = f"<= {_num(hi)}"
        elif self.lo_open:
            text = f"> {_num(lo)} and <= {_num(hi)}"
        else:
            text = f"{_num(lo)} .. {_num(hi)}"
        text += f" {self.unit}" if self.unit else ""
        return text + (f" ({self.note})" if self.note else "")

    def core(self, integer: bool) -> Any:
        """The pydantic-core schema of the number itself (its errors are worded by :meth:`tail`)."""
        from pydantic_core import core_schema as cs

        gt = self.lo if self.lo_open else None
        ge = None if self.lo_open else self.lo
        if integer:
            return cs.int_schema(
                strict=True,
                gt=None if gt is None else int(gt),
                ge=None if ge is None else int(ge),
                le=None if self.hi is None else int(self.hi),
            )
        return cs.float_schema(strict=True, allow_inf_nan=False, gt=gt, ge=ge, le=self.hi)

    def tail(self, value: Any, integer: bool) -> str:
        """What follows the key path when ``value`` breaks the rule."""
        if isinstance(value, bool) or not isinstance(value, int | float):
            return f": {short(value)} must be {'an integer' if integer else 'a number'}"
        if integer and isinstance(value, float):
            return f": {short(value)} must be an integer"
        if isinstance(value, int) and not integer and abs(value) > 1e308:
            return f": {short(value)} is too large"
        return f" = {shown(value)}; allowed: {self.describe()}"

    def __get_pydantic_core_schema__(self, source: Any, handler: Any) -> Any:
        from pydantic import ValidationError
        from pydantic_core import core_schema as cs

        integer = source is int

        def check(value: Any, inner: Callable[[Any], Any]) -> Any:
            try:
                return inner(value)
            except ValidationError:
                _raise([_problem(self.tail(value, integer), value=value)])

        return cs.no_info_wrap_validator_function(check, self.core(integer))

    def __get_pydantic_json_schema__(self, schema: Any, handler: Any) -> dict[str, Any]:
        out: dict[str, Any] = handler(schema)
        if self.unit:
            out["unit"] = self.unit
        return out


@dataclass(frozen=True)
class Vec:
    """A list of numbers, each :class:`Num` ``item``: exactly ``n`` of them, or ``min_n`` to
    ``max_n``. Each bad element is its own problem (``key[2] = nan; allowed: …``)."""

    item: Num = Num()
    n: int | None = None
    min_n: int = 0
    max_n: int | None = None
    note: str = ""

    def describe(self) -> str:
        if self.n is not None:
            count = f"{self.n}"
        elif self.max_n is None:
            count = f"at least {self.min_n}" if self.min_n else "any number of"
        else:
            count = f"{self.min_n} to {self.max_n}" if self.min_n else f"at most {self.max_n}"
        note = f" ({self.note})" if self.note else ""
        return f"{count} values{note}, each {self.item.describe()}"

    def __get_pydantic_core_schema__(self, source: Any, handler: Any) -> Any:
        from pydantic import ValidationError
        from pydantic_core import core_schema as cs

        integer = get_args(source) == (int,)
        low = self.n if self.n is not None else self.min_n
        high = self.n if self.n is not None else self.max_n
        inner = cs.list_schema(
            self.item.core(integer), min_length=low, max_length=high, strict=True
        )

        def check(value: Any, validate: Callable[[Any], Any]) -> Any:
            if not isinstance(value, list):
                _raise([_problem(f": {short(value)} must be a list", value=value)])
            if len(value) < low or (high is not None and len(value) > high):
                text = shown(value)
                text = text if len(text) <= 60 else f"{text[:59]}… ({len(value)} values)"
                _raise([_problem(f" = {text}; allowed: {self.describe()}", value=value)])
            try:
                return validate(value)
            except ValidationError as exc:
                bad = sorted({int(e["loc"][0]) for e in exc.errors() if e["loc"]})
                _raise([_problem(self.item.tail(value[i], integer), (i,), value[i]) for i in bad])

        return cs.no_info_wrap_validator_function(check, inner)

    def __get_pydantic_json_schema__(self, schema: Any, handler: Any) -> dict[str, Any]:
        out: dict[str, Any] = handler(schema)
        if self.item.unit:
            out["unit"] = self.item.unit
        return out


@dataclass(frozen=True)
class Choice:
    """One of ``values`` (strings)."""

    values: tuple[str, ...]

    def describe(self) -> str:
        return ", ".join(self.values)

    def __get_pydantic_core_schema__(self, source: Any, handler: Any) -> Any:
        from pydantic_core import core_schema as cs

        def check(value: Any) -> Any:
            if not isinstance(value, str) or value not in self.values:
                _raise([_problem(f" = {short(value)}; allowed: {self.describe()}", value=value)])
            return value

        return cs.no_info_plain_validator_function(
            check, json_schema_input_schema=cs.literal_schema(list(self.values))
        )


@dataclass(frozen=True)
class Rule:
    """A further check of a value that is valid on its own: ``check(value)`` yields every
    :data:`Problem` (none: the value is good)."""

    check: Callable[[Any], Iterable[Problem]]
    doc: str = ""
    """What the rule allows, for the documentation (empty: said by the key's docstring)."""
    raw: bool = False
    """Check the value as given, before (and besides) its own validation: e.g. the keys of a
    table, whatever its values are."""

    def describe(self) -> str:
        return self.doc

    def __get_pydantic_core_schema__(self, source: Any, handler: Any) -> Any:
        from pydantic import ValidationError
        from pydantic_core import core_schema as cs

        def after(value: Any) -> Any:
            _raise_problems(self.check(value), value)
            return value

        def first(value: Any, validate: Callable[[Any], Any]) -> Any:
            details: list[InitErrorDetails] = []
            try:
                after(value)
            except ValidationError as exc:
                details += _details(exc)
            try:
                value = validate(value)
            except ValidationError as exc:
                details += _details(exc)
            if details:
                _raise(details)
            return value

        if self.raw:
            return cs.no_info_wrap_validator_function(first, handler(source))
        return cs.no_info_after_validator_function(after, handler(source))


@dataclass(frozen=True)
class Spread:
    """On a :class:`Table` of numbers keyed by ``names``: one number stands for all of them
    (``squareness = 1.0`` is ``{alpha = 1.0, beta1 = 1.0, beta2 = 1.0}``); ``item`` its rule."""

    names: tuple[str, ...]
    item: Num

    def __get_pydantic_core_schema__(self, source: Any, handler: Any) -> Any:
        from pydantic import ValidationError
        from pydantic_core import SchemaValidator
        from pydantic_core import core_schema as cs

        number = SchemaValidator(self.item.core(integer=False))

        def spread(value: Any) -> Any:
            if isinstance(value, Mapping):
                return value
            try:
                checked = number.validate_python(value)
            except ValidationError:
                _raise([_problem(self.item.tail(value, False), value=value)])
            return dict.fromkeys(self.names, checked)

        return cs.no_info_before_validator_function(spread, handler(source))


def _raise_problems(problems: Iterable[Problem], value: Any) -> None:
    details = [
        _problem(p, value=value) if isinstance(p, str) else _problem(p[1], p[0], value)
        for p in problems
    ]
    if details:
        _raise(details)


# ------------------------------------------------------------------------------------ tables
class Table:
    """Mixin of the dataclasses that describe a TOML table: unknown keys are refused (naming the
    allowed ones), every scalar is strict, :meth:`rules` checks the keys together. Fields in
    ``NOT_IN_FILE`` are attributes of the object, not keys of the file."""

    __pydantic_config__: ClassVar[dict[str, Any]] = {
        "extra": "forbid",  # unknown keys are refused (and named) before pydantic sees them
    }
    NOT_IN_FILE: ClassVar[frozenset[str]] = frozenset()

    @classmethod
    def unknown_key(cls, key: str, value: Any) -> str | None:
        """The problem of a key the table does not have (None: it is kept, unchecked)."""
        return f"unknown key {{path}}; allowed: {', '.join(sorted(cls.toml_keys()))}"

    def rules(self, context: Mapping[str, Any]) -> Iterable[Problem]:
        """Problems of the keys together (none here). Keys with a problem of their own are at
        their defaults then, and named in ``context["bad"]``: a rule judges only keys that are
        :func:`usable`; ``context["unknown"]`` names the unknown keys (perhaps known ones
        misspelt)."""
        return ()

    @classmethod
    def toml_keys(cls) -> tuple[str, ...]:
        """The keys of the table, in declaration order."""
        return tuple(
            f.name
            for f in dataclasses.fields(cls)  # type: ignore[arg-type]
            if f.init and f.name not in cls.NOT_IN_FILE
        )

    @classmethod
    def __get_pydantic_core_schema__(cls, source: Any, handler: Any) -> Any:
        from pydantic_core import core_schema as cs

        schema = handler(source)
        _strict_scalars(schema)
        return cs.with_info_wrap_validator_function(cls._validate_table, schema)

    @classmethod
    def _missing(cls, detail: InitErrorDetails) -> InitErrorDetails:
        return _describe_missing(cls, detail)

    @classmethod
    def _validate_table(cls, data: Any, handler: Callable[[Any], Any], info: Any) -> Any:
        from pydantic import ValidationError

        if not isinstance(data, Mapping):
            _raise([_problem(f"[{{path}}] must be a table, got {short(data)}", value=data)])
        keys = cls.toml_keys()
        details = []
        for k, v in data.items():
            why = None if k in keys else cls.unknown_key(k, v)
            if why is not None:
                details.append(_problem(why, (str(k),), v))
        unknown = frozenset(str(k) for k in data if k not in keys)
        known = {k: v for k, v in data.items() if k in keys}
        bad: set[str] = set()
        try:
            obj = handler(known)
        except ValidationError as exc:
            details += [cls._missing(d) for d in _details(exc)]
            bad = {str(d["loc"][0]) for d in details if d["loc"]}
            try:  # the keys with a problem at their defaults: the rules judge the others
                obj = handler({k: v for k, v in known.items() if k not in bad})
            except ValidationError:
                obj = None
        context = {**(info.context or {}), "bad": frozenset(bad), "unknown": unknown}
        if obj is not None and context.get("rules", True):
            try:
                _raise_problems(obj.rules(context), data)
            except ValidationError as exc:
                details += _details(exc)
        if details:
            _raise(details, cls.__name__)
        return obj


def _describe_missing(cls: type, detail: InitErrorDetails) -> InitErrorDetails:
    if detail["type"] != "missing" or len(detail["loc"]) != 1:
        return detail
    rule = rule_of(cls, str(detail["loc"][0]))
    what = f": {rule.describe()}" if rule is not None else ""
    return _problem(f"{{path}} is required{what}", detail["loc"], None)


def usable(context: Mapping[str, Any], *keys: str) -> bool:
    """None of ``keys`` (of the table whose :meth:`Table.rules` runs) had a problem of its own."""
    return not set(keys) & context.get("bad", frozenset())


def _strict_scalars(schema: Any, root: bool = True) -> None:
    """Make every bool/int/float/str schema in ``schema`` (a core-schema tree) strict; a
    nested table is left to its own :class:`Table` hook."""
    if isinstance(schema, dict):
        if schema.get("type") in ("bool", "int", "float", "str"):
            schema["strict"] = True
        if schema.get("type") == "dataclass" and not root:
            return
        for value in schema.values():
            _strict_scalars(value, root=False)
    elif isinstance(schema, list):
        for value in schema:
            _strict_scalars(value, root=False)


# ------------------------------------------------------------------------------------ checking
@functools.cache
def adapter(cls: type) -> TypeAdapter[Any]:
    """The (cached) pydantic validator of ``cls``."""
    from pydantic import TypeAdapter

    return TypeAdapter(cls)


def path_text(loc: Iterable[str | int]) -> str:
    """``('errors', 'dx_x', 'value', 1)`` → ``errors.dx_x.value[1]``."""
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


def problem_lines(exc: ValidationError, source: str) -> list[str]:
    """One line per error of ``exc``: ``<source>: <key path> <problem>``."""
    lines = []
    for err in exc.errors(include_url=False):
        path = path_text(err["loc"])
        kind = err["type"]
        if kind == PROBLEM:
            text = str(err["ctx"]["text"])  # type: ignore[index]
        elif kind == "missing":
            text = "{path} is required"
        elif kind in _TYPE_WORDS:
            text = f": {short(err['input'])} must be {_TYPE_WORDS[kind]}"
        else:
            text = err["msg"]
        if "{path}" in text:
            body = text.replace("{path}", path)
        elif not path:
            body = text.lstrip(": ")
        elif text.startswith((" ", ":")):
            body = path + text
        else:
            body = f"{path}: {text}"
        lines.append(f"{source}: {body}")
    return lines


def validate(cls: type, data: Any, source: str, context: Mapping[str, Any] | None = None) -> Any:
    """``data`` (parsed TOML) checked into a ``cls``; :class:`SchemaError` listing every
    problem, each line naming ``source`` and the key path. ``context`` is passed to rules that
    ask for it (``{"rules": False}`` skips every :meth:`Table.rules`)."""
    from pydantic import ValidationError

    try:
        return adapter(cls).validate_python(data, context=dict(context or {}))
    except ValidationError as exc:
        locs = [tuple(e["loc"]) for e in exc.errors(include_url=False)]
        raise SchemaError(problem_lines(exc, source), locs) from None


def field_docs(cls: type) -> dict[str, str]:
    """The docstring under each field of the dataclass ``cls`` (and its bases), whitespace
    folded: what the documentation says of each key."""
    import ast
    import inspect
    import itertools

    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__[:-1]):
        if not dataclasses.is_dataclass(klass):
            continue
        body = ast.parse(inspect.getsource(klass).lstrip()).body[0].body  # type: ignore[attr-defined]
        for node, after in itertools.pairwise(body):
            doc = getattr(after, "value", None)
            text = doc.value if isinstance(doc, ast.Constant) else None
            if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and text:
                docs[node.target.id] = " ".join(str(text).split())
    return docs


def rules_of(cls: type, key: str) -> list[Num | Vec | Choice | Rule]:
    """The rules (:class:`Num`, :class:`Vec`, :class:`Choice`, :class:`Rule`) on ``cls``'s
    field ``key``, in order."""
    import typing

    hint = typing.get_type_hints(cls, include_extras=True)[key]
    found = []
    for arg in (hint, *get_args(hint)):
        for meta in getattr(arg, "__metadata__", ()):
            if isinstance(meta, Num | Vec | Choice | Rule):
                found.append(meta)
            elif isinstance(meta, Spread):
                found.append(meta.item)
    return found


def rule_of(cls: type, key: str) -> Num | Vec | Choice | None:
    """The :class:`Num`, :class:`Vec` or :class:`Choice` of ``cls``'s field ``key`` (or None)."""
    return next((r for r in rules_of(cls, key) if not isinstance(r, Rule)), None)


def describe_rules(cls: type, key: str) -> str:
    """What ``cls``'s field ``key`` allows, in words (``0 .. 2032; a multiple of 0x10``)."""
    texts = [r.describe() for r in rules_of(cls, key) if r.describe()]
    return "; ".join(texts)
