"""How the API says values and sizes: a refusal echoes a JSON value as JSON (true, "8", null), not as
Python writes it (True, '8', None), and a byte limit in the unit it was set in (256 MiB)."""

from __future__ import annotations

import ast
import json
import re

# "got 'x'", "got True": the value a library sentence echoes (models.params.shown is Python's repr)
_ECHOED = re.compile(r"""\bgot ('(?:[^'\\]|\\.)*'|"(?:[^"\\]|\\.)*"|True\b|False\b|None\b)""")


def json_value(value) -> str:
    """A scalar as JSON writes it ("8", true, null, 2.5); anything else by its kind."""
    if isinstance(value, str | bool | int | float) or value is None:
        return json.dumps(value, ensure_ascii=False)
    kind = {"dict": "object", "list": "list", "tuple": "list"}.get(type(value).__name__, type(value).__name__)
    return f"{'an' if kind[:1] in 'aeiou' else 'a'} {kind}"


def json_values(sentence: str) -> str:
    """The library's sentence with the values it echoes said as JSON: "k must be an integer, got '8'"
    -> 'k must be an integer, got "8"', "got True" -> "got true"."""

    def said(m: re.Match) -> str:
        try:
            return "got " + json_value(ast.literal_eval(m.group(1)))
        except (ValueError, SyntaxError):
            return m.group(0)

    return _ECHOED.sub(said, sentence)


def said_bytes(n: int) -> str:
    """A size as people set it: 268435456 -> "256 MiB", 1.5 GiB -> "1.5 GiB", 100 -> "100 bytes"."""
    for unit, size in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if n >= size:
            return f"{n // size} {unit}" if n % size == 0 else f"{n / size:.1f} {unit}"
    return f"{n} byte{'s' if n != 1 else ''}"
