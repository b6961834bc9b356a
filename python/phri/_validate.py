"""One way to validate configuration, for task files, robot descriptions, the study and episode
settings: errors name where the value came from (a file and its key, or the settings object), what
was expected and what was given, and suggest a near match for a misspelt name."""

from __future__ import annotations

import difflib
import ipaddress
import math
import sys
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from phri.exceptions import ConfigError, InvalidParameterError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = [
    "Reader",
    "check_loopback",
    "did_you_mean",
    "finite",
    "is_integer",
    "must_be",
    "parse_toml",
    "unknown_key",
]

_NOTHING: Any = object()


def check_loopback(host: str) -> str:
    """`host` if it is a loopback address (127.x.y.z): phri's servers (the FR3 simulator, the replay)
    serve nowhere else."""
    try:
        address = ipaddress.ip_address(host)
        ok = address.version == 4 and address.is_loopback
    except ValueError:
        ok = False
    if not ok:
        raise InvalidParameterError(f"host must be a loopback address 127.x.y.z, got {host!r}")
    return host


def must_be(
    what: str, expected: str, got: Any = _NOTHING, *, error: type[Exception] = ConfigError, show: Any = repr
) -> Exception:
    """The error "{what} must be {expected}, got {show(got)}" of class `error`: `what` names where
    the value came from ("file.toml: key 'duration'", "study: seed", "sample_rate")."""
    got_text = "" if got is _NOTHING else f", got {show(got)}"
    return error(f"{what} must be {expected}{got_text}")


def is_integer(v: Any) -> bool:
    """An integer (Python or numpy), not a boolean."""
    return isinstance(v, int | np.integer) and not isinstance(v, bool)


def did_you_mean(name: str, known: Sequence[str]) -> str:
    """ "; did you mean 'x'?" for the closest of `known` to `name`, or ""."""
    close = difflib.get_close_matches(name, list(known), n=1)
    return f"; did you mean '{close[0]}'?" if close else ""


def finite(x: Any) -> bool:
    """A TOML number (not a boolean) that is finite as a float (huge integers are not)."""
    if isinstance(x, bool) or not isinstance(x, int | float):
        return False
    try:
        return math.isfinite(x)
    except OverflowError:
        return False


def unknown_key(source: str, path: str, key: str, allowed: tuple[str, ...]) -> ConfigError:
    """An error for `key` in the table at `path` ("" for the top level): the allowed keys, a near match."""
    table = f"table [{path}]" if path else "the top-level table"
    full = f"{path}.{key}" if path else key
    return ConfigError(
        f"{source}: unknown key '{full}' in {table}; allowed keys: {', '.join(allowed)}"
        f"{did_you_mean(key, allowed)}"
    )


class Reader:
    """Typed access to a TOML table with errors that name the file and key.

    With `allowed`, a key the table does not know is an error (a typo must not fall back to a default).
    """

    def __init__(
        self, source: str, table: dict[str, Any], prefix: str = "", allowed: tuple[str, ...] | None = None
    ) -> None:
        self.source, self.table, self.prefix = source, table, prefix
        if allowed is not None:
            for key in table:
                if key not in allowed:
                    raise unknown_key(source, prefix.rstrip("."), key, allowed)

    def fail(self, key: str, expected: str, got: Any = _NOTHING) -> Exception:
        return must_be(f"{self.source}: key '{self.prefix}{key}'", expected, got)

    def get(self, key: str, default: Any = ...) -> Any:
        if key in self.table:
            return self.table[key]
        if default is ...:
            raise ConfigError(f"{self.source}: missing key '{self.prefix}{key}'")
        return default

    def number(
        self, key: str, default: Any = ..., positive: bool = False, expected: str = "a finite number"
    ) -> float:
        """A finite number from the file; a default that is not in the file may be infinite."""
        if key not in self.table and default is not ...:
            return float(default)
        v = self.get(key)
        if not finite(v):
            raise self.fail(key, expected, v)
        if positive and not v > 0:
            raise self.fail(key, "a number > 0", v)
        return float(v)

    def string(self, key: str, default: Any = ...) -> str:
        v = self.get(key, default)
        if not isinstance(v, str):
            raise self.fail(key, "a string", v)
        return v

    def optional_string(self, key: str) -> str | None:
        """A string, or None when the table has no `key`."""
        return self.string(key) if key in self.table else None

    def vector(self, key: str, length: int, default: Any = ...) -> np.ndarray:
        v = self.get(key, default)
        ok = isinstance(v, list | tuple) and len(v) == length and all(finite(x) for x in v)
        if not ok:
            raise self.fail(key, f"a list of {length} finite numbers", v)
        return np.asarray(v, dtype=float)

    def named_tables(
        self, key: str, example: str, entry: str, allowed: tuple[str, ...]
    ) -> list[tuple[str, Reader]]:
        """The [key.<name>] tables (none if `key` is absent) as (name, Reader) pairs, each one's keys
        checked against `allowed`; `example` names one in errors, `entry` says what each must be."""
        table = self.get(key, {})
        if not isinstance(table, dict):
            raise self.fail(key, f"a table of object tables, e.g. [{self.prefix}{key}.{example}]", table)
        readers = []
        for name, spec in table.items():
            if not isinstance(spec, dict):
                raise self.fail(f"{key}.{name}", entry, spec)
            readers.append((name, Reader(self.source, spec, f"{self.prefix}{key}.{name}.", allowed)))
        return readers

    def table_of(self, key: str, allowed: tuple[str, ...]) -> Reader:
        """The sub-table `key` (empty if absent), its keys checked against `allowed`."""
        v = self.get(key, {})
        if not isinstance(v, dict):
            raise self.fail(key, f"a table, e.g. [{self.prefix}{key}]", v)
        return Reader(self.source, v, f"{self.prefix}{key}.", allowed)


def decode_utf8(raw: bytes, error: Callable[[int, int, bytes], Exception]) -> str:
    """`raw` as UTF-8 text without its byte-order mark (some editors and Excel write one), with
    universal newlines; bytes that are not UTF-8 raise ``error(line, offset, bad_bytes)``."""
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise error(raw[: e.start].count(b"\n") + 1, e.start, raw[e.start : e.end]) from None
    return text.replace("\r\n", "\n").replace("\r", "\n")


def parse_toml(text: str, source: str, what: str, error: type[Exception] = ConfigError) -> dict[str, Any]:
    """`text` parsed as TOML; an `error` naming `source` when it is not TOML, or is TOML that
    Python's parser cannot hold (an integer of thousands of digits, arrays nested thousands deep).
    `what` names the kind of file ("a task file")."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise error(f"{source}: not valid TOML ({e})") from None
    except (ValueError, RecursionError) as e:
        raise error(f"{source}: not {what} phri can read ({type(e).__name__}: {e})") from None
