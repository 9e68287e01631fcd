"""One config system: YAML files in ``configs/`` loaded into typed dataclasses.

Every knob is declared once with :func:`knob`, which carries its documentation and what values it
allows; ``egograph <cmd> --show-config`` prints the values and those docs (:func:`describe`, or
:func:`to_yaml` for a file that loads back). Command lines override any knob with
``--set dotted.key=value`` (the value is parsed as YAML, so ``--set synth.rgb=false`` or
``--set synth.room_size=[6,5,2.6]`` work).

:func:`load_config` checks every knob against its declaration, then each section's cross-knob rules
(``cross_check``), and stops at the first problem with one line naming where the value came from
(``file.yaml:LINE`` or ``--set key=value``), the dotted key, the value and what is allowed::

    --set lift.mode=bogus: lift.mode must be one of robust, reference
    configs/x.yaml:4: graph.chunk_s must be > 0 (got -1.0)
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import textwrap
import types
import typing
from pathlib import Path
from typing import Any, Iterable, Sequence, TypeVar

import yaml

from egograph.core.errors import ConfigError

T = TypeVar("T")


# --------------------------------------------------------------------------- declaring knobs


@dataclasses.dataclass(frozen=True)
class Rule:
    """What values one knob allows. Bounds apply to a number, or to every item of a list.

    ``min``/``max`` are inclusive, ``gt``/``lt`` exclusive; ``length`` is the list length (or the
    allowed lengths); ``ordered`` asks a list not to decrease (a ``[low, high]`` range). NaN is
    never allowed.
    """

    choices: tuple | None = None
    min: float | None = None
    max: float | None = None
    gt: float | None = None
    lt: float | None = None
    length: int | tuple[int, ...] | None = None
    ordered: bool = False

    def allowed(self) -> str:
        """The bound in words: ``"> 0"``, ``"in [0, 1]"``, ``">= 1"``; ``""`` without bounds."""
        lo = (f"[{_num(self.min)}", self.min) if self.min is not None else (f"({_num(self.gt)}", self.gt)
        hi = (f"{_num(self.max)}]", self.max) if self.max is not None else (f"{_num(self.lt)})", self.lt)
        if lo[1] is not None and hi[1] is not None:
            return f"in {lo[0]}, {hi[0]}"
        if lo[1] is not None:
            return (">= " if self.min is not None else "> ") + _num(lo[1])
        if hi[1] is not None:
            return ("<= " if self.max is not None else "< ") + _num(hi[1])
        return ""

    def summary(self) -> str:
        """Everything allowed, in words (``"one of robust, reference"``, ``"2 items >= 0, low <= high"``)."""
        parts = []
        if self.choices is not None:
            parts.append("one of " + ", ".join(str(c) for c in self.choices))
        if self.length is not None:
            lengths = (self.length,) if isinstance(self.length, int) else self.length
            parts.append(" or ".join(map(str, lengths)) + " items")
        if self.allowed():
            parts.append(self.allowed())
        if self.ordered:
            parts.append("low <= high")
        return ", ".join(parts)

    def problem(self, value: Any) -> str | None:
        """Why ``value`` is not allowed (``"must be ..."``), or None when it is."""
        if value is None:
            return None
        if self.choices is not None and value not in self.choices:
            return "must be one of " + ", ".join(str(c) for c in self.choices)
        if isinstance(value, (list, tuple)):
            lengths = (self.length,) if isinstance(self.length, int) else self.length
            if lengths is not None and len(value) not in lengths:
                return f"must have {' or '.join(map(str, lengths))} item{'' if lengths == (1,) else 's'}"
            for item in value:
                bad = self._number_problem(item)
                if bad:
                    return "items " + bad
            if self.ordered and any(b < a for a, b in zip(value, value[1:])):
                return "must not decrease ([low, high])"
            return None
        return self._number_problem(value)

    def _number_problem(self, x: Any) -> str | None:
        if isinstance(x, bool) or not isinstance(x, (int, float)):
            return None if self.allowed() == "" else "must be a number"
        if isinstance(x, float) and math.isnan(x):
            return "must be a number, not NaN"
        ok = ((self.min is None or x >= self.min) and (self.max is None or x <= self.max)
              and (self.gt is None or x > self.gt) and (self.lt is None or x < self.lt))
        return None if ok else "must be " + self.allowed()


def _num(x: float | None) -> str:
    return f"{x:g}" if isinstance(x, float) else str(x)


def knob(default: Any, doc: str, *, choices: Sequence | None = None, min: float | None = None,
         max: float | None = None, gt: float | None = None, lt: float | None = None,
         length: int | tuple[int, ...] | None = None, ordered: bool = False) -> Any:
    """A config field with its documentation (units included) and allowed values in one place.

    ``choices``: the allowed values (strings); ``min``/``max``: inclusive bounds; ``gt``/``lt``:
    exclusive bounds (bounds apply to each item of a list); ``length``: a list's length, or a tuple
    of allowed lengths; ``ordered``: a list must not decrease. :func:`load_config` and
    :func:`check_config` enforce them; ``knob(default, doc)`` alone allows any value of the type.
    """
    rule = Rule(tuple(choices) if choices is not None else None, min, max, gt, lt, length, ordered)
    meta = {"doc": doc, "rule": rule}
    if isinstance(default, (list, dict, set)) or dataclasses.is_dataclass(default):
        value = default
        return dataclasses.field(default_factory=lambda: _copy(value), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def section(cls: type, doc: str) -> Any:
    """A nested config section (a dataclass with its own knobs)."""
    return dataclasses.field(default_factory=cls, metadata={"doc": doc})


def _copy(value: Any) -> Any:
    if dataclasses.is_dataclass(value):
        return dataclasses.replace(value)
    return type(value)(value)


# --------------------------------------------------------------------------- checking


class KnobError(ConfigError):
    """A value its knob (or a cross-knob rule) does not allow.

    ``keys`` are dotted and relative to the config :func:`check_config` was given; ``template``
    holds one ``{}`` per key; ``values`` are the offending values, in key order.
    """

    def __init__(self, keys: Sequence[str], template: str, values: Sequence[Any]):
        self.keys = tuple(keys)
        self.template = template
        self.values = tuple(values)
        super().__init__(self.render())

    def render(self, show_values: bool = True) -> str:
        text = self.template.format(*self.keys)
        if show_values:
            if len(self.keys) == 1:
                text += f" (got {excerpt(self.values[0])})"
            else:
                text += " (got " + ", ".join(f"{k}={excerpt(v, 80)}" for k, v in zip(self.keys, self.values)) + ")"
        return text

    def under(self, prefix: str) -> KnobError:
        """The same error with ``prefix.`` in front of every key."""
        return KnobError([f"{prefix}.{k}" for k in self.keys], self.template, self.values)


def rule_error(cfg: Any, template: str, *names: str) -> KnobError:
    """The error of a cross-knob rule of ``cfg``: ``template`` has one ``{}`` per knob name, e.g.
    ``rule_error(self, "{} must be < {}", "min_range", "max_range")``."""
    return KnobError(names, template, [getattr(cfg, n) for n in names])


def check_config(cfg: Any) -> None:
    """Raise :class:`KnobError` (a ConfigError) at the first knob of ``cfg`` (a config dataclass,
    nested sections included) outside its declaration, or the first broken ``cross_check`` rule."""
    for f in dataclasses.fields(cfg):
        value = getattr(cfg, f.name)
        if dataclasses.is_dataclass(value):
            try:
                check_config(value)
            except KnobError as exc:
                raise exc.under(f.name) from None
            continue
        rule = f.metadata.get("rule")
        bad = rule.problem(value) if rule is not None else None
        if bad:
            raise KnobError([f.name], "{} " + bad, [value])
    cross = getattr(cfg, "cross_check", None)
    if cross is not None:
        cross()


class Checked:
    """Base of every config dataclass: :meth:`check` validates its knobs and sections.

    A section with rules across knobs overrides :meth:`cross_check` and raises :func:`rule_error`.
    """

    def check(self) -> None:
        """Raise ConfigError (naming the key relative to this section) on a value the stage cannot use."""
        check_config(self)

    def cross_check(self) -> None:
        """Rules that involve more than one knob; none by default."""


# --------------------------------------------------------------------------- building


MAX_INT = 2**31 - 1
"""The largest integer a knob takes (a 32-bit C int: the libraries behind the knobs take them)."""

MAX_YAML_NODES = 100_000
"""The most values a config file or ``--set`` value may expand to through YAML aliases (the
packaged configs have about 1,000): a few hundred bytes of nested anchors otherwise expand to
billions (the "billion laughs")."""

EXCERPT = 200
"""The longest excerpt of a value an error line quotes, in characters."""


def _cut(text: str, limit: int = EXCERPT) -> str:
    """``text`` on one line, at most ``limit`` characters."""
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def excerpt(value: Any, limit: int = EXCERPT) -> str:
    """``repr(value)`` cut to ``limit`` characters on one line (without building a huge repr)."""
    import reprlib

    r = reprlib.Repr()
    r.maxlist = r.maxtuple = r.maxdict = r.maxset = 12
    r.maxstring = r.maxother = limit
    r.maxlevel = 3
    text = " ".join(r.repr(value).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def check_yaml_size(text: str, where: str) -> None:
    """ConfigError when ``text`` expands to more than :data:`MAX_YAML_NODES` values through
    aliases; measured on the composed node graph (aliases shared, never expanded)."""
    if "*" not in text:
        return
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError:
        return  # the loader says why, naming the line
    sizes: dict[int, int] = {}

    def size(n) -> int:
        got = sizes.get(id(n))
        if got is not None:
            return got
        sizes[id(n)] = 1  # a recursive alias counts once
        total = 1
        if isinstance(n, yaml.SequenceNode):
            total += sum(size(c) for c in n.value)
        elif isinstance(n, yaml.MappingNode):
            total += sum(size(k) + size(v) for k, v in n.value)
        total = min(total, MAX_YAML_NODES + 1)
        sizes[id(n)] = total
        return total

    if node is not None and size(node) > MAX_YAML_NODES:
        raise ConfigError(f"{where}: YAML aliases expand to more than {MAX_YAML_NODES:,} values (nested "
                          "anchors?); refused")


def _coerce(value: Any, hint: Any, where: str, ctx: _Context) -> Any:
    origin = typing.get_origin(hint)
    if dataclasses.is_dataclass(hint):
        if not isinstance(value, dict):
            raise ctx.error(where, f"{where} must be a mapping (a section)", value)
        return _build(hint, value, where, ctx)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        if value is None:
            return None
        return _coerce(value, args[0], where, ctx)
    if origin in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise ctx.error(where, f"{where} must be a list", value)
        args = typing.get_args(hint)
        inner = args[0] if args else Any
        items = [_coerce(v, inner, f"{where}[{i}]", ctx) for i, v in enumerate(value)]
        return tuple(items) if origin is tuple else items
    if origin is dict:
        if not isinstance(value, dict):
            raise ctx.error(where, f"{where} must be a mapping", value)
        return dict(value)
    if hint is Any:
        return value
    if hint is bool:
        if isinstance(value, bool):
            return value
        raise ctx.error(where, f"{where} must be true or false", value)
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                value = int(value)
            else:
                raise ctx.error(where, f"{where} must be an integer", value)
        if abs(value) > MAX_INT:  # the C libraries (GTSAM, Open3D, numpy indices) take 32-bit ints
            raise ctx.error(where, f"{where} must be an integer of at most {MAX_INT} in size", value)
        return value
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ctx.error(where, f"{where} must be a number", value)
        if math.isinf(value):  # NaN: the knob's rule says "not NaN"
            raise ctx.error(where, f"{where} must be a finite number", value)
        return float(value)
    if hint is str:
        if not isinstance(value, str):
            hint_text = f" (YAML reads that as {value!r}; quote it)" if isinstance(value, (bool, int, float)) else ""
            raise ctx.error(where, f"{where} must be a string{hint_text}", value)
        return value
    return value


def _build(cls: type[T], data: dict, where: str, ctx: _Context) -> T:
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    unknown = sorted(set(data) - set(names), key=str)
    if unknown:
        key = f"{where}.{unknown[0]}" if where else str(unknown[0])
        raise ctx.error(key, ctx.unknown(key, where, names))
    base = cls()
    kwargs = {}
    for f in dataclasses.fields(cls):
        if f.name in data:
            kwargs[f.name] = _coerce(data[f.name], hints[f.name], f"{where}.{f.name}" if where else f.name, ctx)
        else:
            kwargs[f.name] = getattr(base, f.name)
    return cls(**kwargs)


@dataclasses.dataclass
class _Context:
    """Where each given value came from (``file.yaml:LINE`` or ``--set key=value``), by dotted key."""

    root: type
    origins: dict[str, str] = dataclasses.field(default_factory=dict)

    def origin(self, key: str) -> str | None:
        """The origin of ``key``, else of the nearest enclosing key that was given (a whole
        section), else of the first key given inside it (an unknown section)."""
        key = key.split("[", 1)[0]
        parts = key.split(".")
        for n in range(len(parts), 0, -1):
            got = self.origins.get(".".join(parts[:n]))
            if got is not None:
                return got
        return next((v for k, v in self.origins.items() if k.startswith(key + ".")), None)

    def error(self, key: str, message: str, value: Any = dataclasses.MISSING) -> ConfigError:
        where = self.origin(key)
        if value is not dataclasses.MISSING and not (where or "").startswith("--set"):
            message += f" (got {excerpt(value)})"
        return ConfigError(f"{where}: {message}" if where else message)

    def unknown(self, key: str, where: str, names: Sequence[str]) -> str:
        near = nearest_key(key, known_keys(self.root))
        if near:
            return f"unknown key {key} (did you mean {near}?)"
        return f"unknown key {key}; {where or 'the top level'} has {', '.join(names)}"

    def knob_error(self, exc: KnobError) -> ConfigError:
        wheres = list(dict.fromkeys(w for w in (self.origin(k) for k in exc.keys) if w))
        single_set = len(exc.keys) == 1 and len(wheres) == 1 and wheres[0].startswith("--set")
        text = exc.render(show_values=not single_set)
        return ConfigError(f"{', '.join(wheres)}: {text}" if wheres else text)


def nearest_key(key: str, candidates: Sequence[str], cutoff: float = 0.7) -> str | None:
    """The candidate whose last part is most like ``key``'s (difflib ratio >= ``cutoff``, or it starts
    with it); ties go to the candidate most like the whole dotted key, so ``graph.kernel`` finds
    ``graph.noise.kernel``."""
    def ratio(a: str, b: str) -> float:
        if len(a) >= 4 and b.startswith(a):  # a knob's name typed short: kf_reset for kf_reset_distance_m
            return 1.0 if a == b else 0.9
        return difflib.SequenceMatcher(None, a, b).ratio()

    leaf = key.rsplit(".", 1)[-1]
    scored = [(ratio(leaf, c.rsplit(".", 1)[-1]), ratio(key, c), c) for c in candidates]
    best = max(scored, default=None)
    return best[2] if best is not None and best[0] >= cutoff else None


def known_keys(cls: type) -> list[str]:
    """Every dotted key of a config class: sections and knobs."""
    out = []
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        out.append(f.name)
        if dataclasses.is_dataclass(hints[f.name]):
            out += [f"{f.name}.{k}" for k in known_keys(hints[f.name])]
    return out


# --------------------------------------------------------------------------- loading


def to_dict(cfg: Any) -> dict:
    """Plain nested dict of a config (tuples become lists), for YAML/JSON metadata."""
    def plain(v: Any) -> Any:
        if dataclasses.is_dataclass(v):
            return {f.name: plain(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, (list, tuple)):
            return [plain(x) for x in v]
        return v
    return plain(cfg)


def _parse_override(item: str) -> tuple[list[str], Any]:
    """``"a.b=1"`` -> ``(["a", "b"], 1)``; ConfigError naming the override."""
    key, sep, raw = item.partition("=")
    parts = key.strip().split(".")
    if not sep or not all(p.strip() for p in parts):
        raise ConfigError(f"--set {_cut(item)}: expected dotted.key=value")
    check_yaml_size(raw, f"--set {key.strip()}")
    try:
        value = yaml.safe_load(raw) if raw.strip() else ""
    except yaml.YAMLError as exc:
        reason = " ".join(str(exc).split())
        raise ConfigError(f"--set {_cut(item)}: value is not valid YAML ({_cut(reason)})") from None
    return [p.strip() for p in parts], value


def parse_overrides(overrides: Iterable[str]) -> dict:
    """``["a.b=1", "c=x"]`` -> nested dict ``{"a": {"b": 1}, "c": "x"}``."""
    return _parse_overrides(overrides, {})


def _parse_overrides(overrides: Iterable[str], origins: dict[str, str]) -> dict:
    out: dict = {}
    for item in overrides:
        parts, value = _parse_override(item)
        node = out
        for i, p in enumerate(parts[:-1]):
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise ConfigError(f"--set {_cut(item)}: {'.'.join(parts[:i + 1])} is set both as a value and a section")
        node[parts[-1]] = value
        for key in _dotted_keys(value, ".".join(parts)):
            origins[key] = f"--set {_cut(item)}"
    return out


def _dotted_keys(value: Any, key: str) -> list[str]:
    """``key`` and, for a mapping value, every dotted key inside it."""
    keys = [key]
    if isinstance(value, dict):
        for k, v in value.items():
            keys += _dotted_keys(v, f"{key}.{k}")
    return keys


def _yaml_lines(node: yaml.Node, path: str, prefix: str, out: dict[str, str]) -> None:
    """``{dotted key: "path:LINE"}`` for every key of a composed YAML mapping (lines from 1)."""
    if not isinstance(node, yaml.MappingNode):
        return
    for key_node, value_node in node.value:
        if not isinstance(key_node, yaml.ScalarNode):
            continue
        key = f"{prefix}{key_node.value}"
        out[key] = f"{path}:{key_node.start_mark.line + 1}"
        _yaml_lines(value_node, path, key + ".", out)


def _read_yaml(path: Path, origins: dict[str, str]) -> dict:
    if not path.is_file():
        from egograph.core.resources import resolve_config

        path = resolve_config(path)  # a packaged config by name, or one line saying what was tried
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError(f"{path}: config file unreadable ({exc.strerror})") from None
    check_yaml_size(text, str(path))
    try:
        loaded = yaml.safe_load(text)
        node = yaml.compose(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{path}:{mark.line + 1}" if mark is not None else f"{path}"
        reason = getattr(exc, "problem", None) or " ".join(str(exc).split())
        raise ConfigError(f"{where}: not valid YAML ({reason})") from None
    if loaded is None:
        return {}
    if not isinstance(loaded, dict):
        raise ConfigError(f"{path}: top level must be a mapping")
    if node is not None:
        _yaml_lines(node, str(path), "", origins)
    return loaded


def _lookup(data: dict, key: str) -> Any:
    node: Any = data
    for part in key.split("."):
        node = node.get(part) if isinstance(node, dict) else None
    return node


def _merge(base: dict, extra: dict) -> dict:
    out = dict(base)
    for k, v in extra.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = v
    return out


def load_config(cls: type[T], path: str | Path | None = None, overrides: Iterable[str] = ()) -> T:
    """Defaults of ``cls`` <- YAML file ``path`` <- ``--set`` overrides, then checked.

    Every knob is checked against its :func:`knob` declaration and every section's ``cross_check``
    runs. Errors are ConfigError with one line naming the file and line, or the override, the
    dotted key, the value and what is allowed; unknown keys get the nearest known key.
    """
    ctx = _Context(cls)
    data: dict = {}
    if path is not None:
        data = _read_yaml(Path(path), ctx.origins)
    set_origins: dict[str, str] = {}
    data = _merge(data, _parse_overrides(overrides, set_origins))
    for key in set_origins:  # an override's value replaces what the file said below its key
        if not isinstance(_lookup(data, key), dict):
            for k in [k for k in ctx.origins if k.startswith(key + ".")]:
                del ctx.origins[k]
    ctx.origins.update(set_origins)
    cfg = _build(cls, data, "", ctx)
    try:
        check_config(cfg)
    except KnobError as exc:
        raise ctx.knob_error(exc) from None
    return cfg


# --------------------------------------------------------------------------- showing


def describe(cfg: Any, prefix: str = "") -> list[tuple[str, Any, str]]:
    """``(dotted key, value, doc)`` for every knob, for ``--show-config``."""
    rows = []
    for f in dataclasses.fields(cfg):
        value = getattr(cfg, f.name)
        key = f"{prefix}{f.name}"
        if dataclasses.is_dataclass(value):
            rows.extend(describe(value, key + "."))
        else:
            rows.append((key, value, f.metadata.get("doc", "")))
    return rows


def _yaml_value(value: Any) -> str:
    """One-line YAML of a knob value (flow style: ``[1.0, 2.0]``), exact for floats."""
    text = yaml.safe_dump(to_dict(value), default_flow_style=True, width=math.inf, allow_unicode=True).strip()
    if text.endswith("\n..."):  # the document end marker after a plain scalar
        text = text[: -len("\n...")]
    return text


def _comment(doc: str, indent: str, width: int) -> list[str]:
    if not doc:
        return []
    return [f"{indent}# {line}" for line in textwrap.wrap(doc, max(40, width - len(indent) - 2))]


def to_yaml(cfg: Any, width: int = 100) -> str:
    """The config as YAML that :func:`load_config` reads back to an equal config; each knob's
    (and section's) doc as a comment above it, wrapped at ``width`` columns, and what the knob
    allows as a comment after its value."""
    lines: list[str] = []

    def emit(obj: Any, depth: int) -> None:
        indent = "  " * depth
        for f in dataclasses.fields(obj):
            value = getattr(obj, f.name)
            lines.extend(_comment(f.metadata.get("doc", ""), indent, width))
            if dataclasses.is_dataclass(value):
                lines.append(f"{indent}{f.name}:")
                emit(value, depth + 1)
            else:
                rule = f.metadata.get("rule")
                allowed = f"  # {rule.summary()}" if rule is not None and rule.summary() else ""
                lines.append(f"{indent}{f.name}: {_yaml_value(value)}{allowed}")

    emit(cfg, 0)
    return "\n".join(lines) + "\n"
