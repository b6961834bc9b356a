"""A population of simulated participants: a distribution per parameter, read from a TOML file.

A population file has one ``[parameters.<name>]`` table per parameter of
:data:`~phri.sim.participant.parameters.PARAMETERS`, each a distribution in the parameter's SI unit::

    [parameters.max_force]
    distribution = "lognormal"   # median × exp(sigma · z), z standard normal
    median = 12.0                # N
    sigma = 0.3                  # SD of the natural log (0: everyone alike)
    min = 2.0                    # optional clipping bounds (lognormal and normal)
    max = 40.0

    [parameters.rate]
    distribution = "fixed"
    value = 100.0                # Hz

Distributions: ``fixed`` (value), ``lognormal`` (median, sigma), ``normal`` (mean, sd) and
``uniform`` (low, high); lognormal and normal take optional ``min``/``max`` clips. ``extends =
"default"`` (a shipped population's name or a path relative to the file) takes the parameters the
file does not give from that population; without it every parameter must be given. An optional
``[about]`` table records where the population came from (``description``, ``command``, ``seed``,
``phri_version``, ``date``, ``targets``, ``fit``, and for a calibrated population ``start``: one
``parameter.key = value`` line for each value its calibration started from where this population's
differs, so :meth:`Population.calibration_start` rebuilds the starting population and the recorded
command can be run again without the file it named).

Drawing is keyed, not sequential: participant p of a study with seed s gets, for each parameter, a
uniform number from ``SeedSequence(s, spawn_key=(0, p, crc32(name)))`` and the parameter is that
quantile of its distribution. So the same seed gives the same person (the same quantiles) under
every strategy and in every population: candidate populations in a calibration are compared on
common random numbers, and adding a parameter changes no one's other parameters.
"""

from __future__ import annotations

import functools
import math
import statistics
import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from phri._validate import decode_utf8, did_you_mean, finite, is_integer, must_be, parse_toml
from phri.exceptions import ConfigError, InvalidParameterError, UnknownNameError
from phri.sim.participant.parameters import PARAMETERS

if TYPE_CHECKING:
    from phri.sim.participant.params import ParticipantParams

__all__ = [
    "DISTRIBUTIONS",
    "Distribution",
    "Population",
    "default_population",
    "load_population",
    "population_names",
]

#: Each distribution's own keys (required), and the optional clipping keys it also takes.
DISTRIBUTIONS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "fixed": (("value",), ()),
    "lognormal": (("median", "sigma"), ("min", "max")),
    "normal": (("mean", "sd"), ("min", "max")),
    "uniform": (("low", "high"), ()),
}
ABOUT_KEYS = ("description", "command", "seed", "phri_version", "date", "targets", "fit", "start")
TOP_KEYS = ("about", "extends", "parameters")
#: The keyed draws' spawn-key prefix (the study's participant key).
PARTICIPANT_KEY = 0
#: Uniform numbers are kept this far from 0 and 1 (the normal quantile is infinite there).
_EDGE = 1e-12
_NORMAL = statistics.NormalDist()


@dataclass(frozen=True)
class Distribution:
    """One parameter's distribution across people (values in the parameter's SI unit)."""

    kind: str
    #: The distribution's own values by key (e.g. median and sigma), and the optional clips.
    values: tuple[tuple[str, float], ...]

    def get(self, key: str, default: float | None = None) -> float | None:
        """The value of `key` (e.g. ``"median"``, ``"max"``) in the parameter's SI unit (``sigma``:
        of the natural log, unitless), or `default` if the distribution does not give it."""
        return dict(self.values).get(key, default)

    def quantile(self, u: float) -> float:
        """The value at cumulative probability `u` in (0, 1)."""
        v = dict(self.values)
        u = min(max(u, _EDGE), 1.0 - _EDGE)
        if self.kind == "fixed":
            return v["value"]
        if self.kind == "uniform":
            return v["low"] + (v["high"] - v["low"]) * u
        z = _NORMAL.inv_cdf(u)
        if self.kind == "lognormal":
            spread = v["sigma"] * z  # beyond 709 exp overflows (an error, where x * y gives inf)
            x = v["median"] * math.exp(spread) if spread < 709.0 else math.inf
        else:
            x = v["mean"] + v["sd"] * z
        return min(max(x, v.get("min", -math.inf)), v.get("max", math.inf))

    @property
    def typical(self) -> float:
        """The median person's value."""
        return self.quantile(0.5)

    def to_dict(self) -> dict[str, Any]:
        """The distribution as its ``[parameters.<name>]`` table of a population file:
        ``{"distribution": kind, key: value, ...}``."""
        return {"distribution": self.kind, **dict(self.values)}


@dataclass(frozen=True)
class Population:
    """A distribution per participant parameter (:data:`PARAMETERS` order); two populations are
    equal when their distributions are (where they came from does not count)."""

    distributions: tuple[tuple[str, Distribution], ...]
    source: str = field(default="<memory>", compare=False)
    #: Provenance ([about]): command, seed, phri version, ... as written in the file.
    about: tuple[tuple[str, Any], ...] = field(default=(), compare=False)

    def __getitem__(self, name: str) -> Distribution:
        return dict(self.distributions)[name]

    def typical(self) -> dict[str, float]:
        """Every parameter's median."""
        return {name: d.typical for name, d in self.distributions}

    @staticmethod
    def quantiles(study_seed: int, participant: int) -> dict[str, float]:
        """Participant `participant`'s uniform number per parameter (keyed by the parameter's name).
        Both are integers >= 0 (numpy's SeedSequence takes no other; None would draw at random)."""
        for arg, value in (("study_seed", study_seed), ("participant", participant)):
            if not is_integer(value) or value < 0:
                raise must_be(arg, "an integer >= 0", value, error=InvalidParameterError)
        out = {}
        for name in PARAMETERS:
            ss = np.random.SeedSequence(
                study_seed, spawn_key=(PARTICIPANT_KEY, participant, zlib.crc32(name.encode()))
            )
            out[name] = float(np.random.default_rng(ss).random())
        return out

    def person(self, quantiles: Mapping[str, float]) -> ParticipantParams:
        """The person at these quantiles (a uniform number per parameter)."""
        from phri.sim.participant.params import ParticipantParams

        return ParticipantParams(**{name: d.quantile(quantiles[name]) for name, d in self.distributions})

    def draw(self, study_seed: int, participant: int) -> ParticipantParams:
        """Participant `participant` (1-based) of the study with seed `study_seed`."""
        return self.person(self.quantiles(study_seed, participant))

    def draw_from(self, rng: np.random.Generator) -> ParticipantParams:
        """A person from `rng`'s next uniform numbers, one per parameter in :data:`PARAMETERS` order."""
        return self.person({name: float(rng.random()) for name in PARAMETERS})

    def replace(self, changes: Mapping[tuple[str, str], float], source: str | None = None) -> Population:
        """This population with some distributions' values changed: {(parameter, key): value}, e.g.
        ``{("max_force", "median"): 15.0}``; the result is checked as a file would be."""
        data = self.to_dict()
        for (name, key), value in changes.items():
            data["parameters"][name][key] = float(value)
        return Population.from_dict(data, source or self.source)

    def calibration_start(self) -> Population:
        """The population its calibration started from: this one with the ``[about]`` table's
        ``start`` values put back (without provenance). Save it with :meth:`to_toml` and pass it as
        the recorded command's ``--population`` to run that calibration again. A ConfigError if this
        population records no ``start``."""
        about = dict(self.about)
        if "start" not in about:
            raise ConfigError(f"{self.source}: no key 'about.start': not written by phri calibrate")
        bare = Population(self.distributions, self.source)  # replace() re-reads what to_dict() writes
        return bare.replace(_start_values(self.source, about["start"]), f"{self.source}: key 'about.start'")

    def to_dict(self) -> dict[str, Any]:
        """The population as a parsed population file (``about`` if it has provenance, and
        ``parameters``): :meth:`from_dict` reads it back equal; a study keeps it in ``study.json``."""
        out: dict[str, Any] = {}
        if self.about:
            out["about"] = dict(self.about)
        out["parameters"] = {name: d.to_dict() for name, d in self.distributions}
        return out

    def to_toml(self) -> str:
        """The population as a population file (loads back equal)."""
        lines = []
        if self.about:
            lines.append("[about]")
            for key, value in self.about:
                lines.append(f"{key} = {_toml_value(value)}")
            lines.append("")
        for name, d in self.distributions:
            spec = PARAMETERS[name]
            lines.append(f"[parameters.{name}]  # {spec.unit}: {spec.meaning}")
            lines.append(f'distribution = "{d.kind}"')
            for key, value in d.values:
                lines.append(f"{key} = {value!r}")
            lines.append("")
        return "\n".join(lines)

    @classmethod
    def from_dict(cls, data: Any, source: str = "population", base_dir: Path | None = None) -> Population:
        """From a parsed population file; errors name `source` and the key."""
        if not isinstance(data, Mapping):
            raise ConfigError(f"{source}: expected a table of population keys, got {type(data).__name__}")
        for key in data:
            if key not in TOP_KEYS:
                raise ConfigError(
                    f"{source}: unknown key '{key}'; allowed: {', '.join(TOP_KEYS)}"
                    f"{did_you_mean(key, TOP_KEYS)}"
                )
        about = data.get("about", {})
        if not isinstance(about, Mapping):
            raise ConfigError(f"{source}: key 'about' must be a table, got {about!r}")
        for key, value in about.items():
            if key not in ABOUT_KEYS:
                raise ConfigError(
                    f"{source}: unknown key 'about.{key}'; allowed: {', '.join(ABOUT_KEYS)}"
                    f"{did_you_mean(key, ABOUT_KEYS)}"
                )
            if not isinstance(value, str | int) or isinstance(value, bool):
                raise ConfigError(
                    f"{source}: key 'about.{key}' must be a string or an integer, got {value!r}"
                )
        base: dict[str, Distribution] = {}
        if "extends" in data:
            extends = data["extends"]
            if not isinstance(extends, str) or not extends:
                raise ConfigError(
                    f"{source}: key 'extends' must be a population name or path, got {extends!r}"
                )
            path = Path(extends)
            if base_dir is not None and not path.is_absolute() and _is_path(extends):
                path = base_dir / path
            try:
                base = dict(load_population(path if _is_path(extends) else extends).distributions)
            except (ConfigError, UnknownNameError) as e:
                raise ConfigError(f"{source}: key 'extends': {e}") from None
        table = data.get("parameters", {})
        if not isinstance(table, Mapping):
            raise ConfigError(f"{source}: key 'parameters' must be a table of [parameters.<name>] tables")
        known = tuple(PARAMETERS)
        for name in table:
            if name not in PARAMETERS:
                raise ConfigError(
                    f"{source}: unknown key 'parameters.{name}'; known parameters: {', '.join(known)}"
                    f"{did_you_mean(name, known)}"
                )
        out = []
        for name in PARAMETERS:
            if name in table:
                out.append((name, _distribution(source, name, table[name])))
            elif name in base:
                out.append((name, base[name]))
            else:
                raise ConfigError(
                    f"{source}: missing key 'parameters.{name}' ({PARAMETERS[name].meaning} "
                    f"[{PARAMETERS[name].unit}]); give it, or take the rest from a population with "
                    'extends = "default"'
                )
        if "start" in about:  # its form; whether the values fit is calibration_start()'s question
            _start_values(source, about["start"])
        return cls(tuple(out), source, tuple(about.items()))


def start_record(start: Population, fitted: Population) -> str:
    """The ``about.start`` text of `fitted`, calibrated from `start`: a ``parameter.key = value`` line
    for each of `start`'s values that `fitted` does not have (empty if none: it kept its start);
    :func:`_start_values` reads it back."""
    lines = []
    for (name, before), (_, after) in zip(start.distributions, fitted.distributions, strict=True):
        after_values = dict(after.values)
        for key, value in before.values:
            if after_values.get(key) != value:
                lines.append(f"{name}.{key} = {value!r}")
    return "\n".join(lines)


def _start_values(source: str, text: Any) -> dict[tuple[str, str], float]:
    """The ``about.start`` text's values: {(parameter, key): value}, one ``parameter.key = value``
    per line; a ConfigError naming `source` for anything else."""
    values: dict[tuple[str, str], float] = {}
    if not isinstance(text, str):
        raise ConfigError(f"{source}: key 'about.start' must be a string of 'parameter.key = value' lines")
    for line in text.splitlines():
        if not line.strip():
            continue
        name_key, sep, number = line.partition("=")
        name, dot, key = name_key.strip().partition(".")
        try:
            value = float(number)
        except ValueError:
            value = math.nan
        if not (sep and dot and name in PARAMETERS and key and math.isfinite(value)):
            raise ConfigError(
                f"{source}: key 'about.start': {line.strip()[:80]!r} is not 'parameter.key = number' "
                "with a known parameter"
            )
        values[(name, key)] = value
    return values


def _toml_value(value: Any) -> str:
    if isinstance(value, int):
        return str(value)
    text = str(value)
    if "\n" in text:
        return '"""\n' + text.replace("\\", "\\\\").replace('"""', '\\"\\"\\"') + '"""'
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _distribution(source: str, name: str, spec: Any) -> Distribution:
    """One [parameters.<name>] table, checked against the parameter's allowed range."""
    where = f"{source}: key 'parameters.{name}"
    param = PARAMETERS[name]
    unit = param.unit
    if not isinstance(spec, Mapping):
        raise ConfigError(f"{where}' must be a table with a distribution, got {spec!r}")
    kind = spec.get("distribution")
    if not isinstance(kind, str) or kind not in DISTRIBUTIONS:
        raise ConfigError(
            f"{where}.distribution' must be one of {', '.join(DISTRIBUTIONS)}, got {kind!r}"
            + (did_you_mean(kind, tuple(DISTRIBUTIONS)) if isinstance(kind, str) else "")
        )
    required, optional = DISTRIBUTIONS[kind]
    allowed = ("distribution", *required, *optional)
    values: dict[str, float] = {}
    for key, value in spec.items():
        if key == "distribution":
            continue
        if key not in allowed:
            raise ConfigError(
                f"{where}.{key}': unknown key for a {kind} distribution; allowed: {', '.join(allowed)}"
                f"{did_you_mean(key, allowed)}"
            )
        if not finite(value):
            raise ConfigError(f"{where}.{key}' must be a finite number, got {value!r}")
        values[key] = float(value)
    for key in required:
        if key not in values:
            raise ConfigError(
                f"{where}.{key}' is missing (a {kind} distribution needs {', '.join(required)})"
            )

    def bad(key: str, expected: str) -> ConfigError:
        return ConfigError(f"{where}.{key}' must be {expected}, got {values[key]!r}")

    for key in ("sigma", "sd"):
        if key in values and values[key] < 0:
            raise bad(key, "a spread >= 0 (0: everyone alike)")
    if kind == "lognormal" and values["median"] <= 0:
        raise bad("median", f"> 0 [{unit}] (a lognormal is positive)")
    if kind == "uniform" and values["low"] > values["high"]:
        raise bad("low", f"<= high ({values['high']:g})")
    if "min" in values and "max" in values and values["min"] > values["max"]:
        raise bad("min", f"<= max ({values['max']:g})")
    dist = Distribution(kind, tuple(values.items()))
    # Every person drawn must be a valid person: check the distribution's range (its extremes).
    lo, hi = dist.quantile(0.0), dist.quantile(1.0)
    for bound, x in (("min", lo), ("max", hi)):
        if param.allows(x):
            continue
        # Name the key that puts the extreme out of range: a clip, else the distribution's own value.
        key = {"fixed": "value", "uniform": "low" if bound == "min" else "high"}.get(kind, bound)
        if key not in values:
            key = "median" if kind == "lognormal" else "mean"
        hint = (
            f" (a {kind} distribution reaches {x:g}; clip it with min/max)"
            if kind in ("normal", "lognormal")
            else ""
        )
        raise ConfigError(
            f"{where}.{key}' must keep {name} {param.expected} [{unit}] ({param.meaning}), "
            f"got {values[key]!r}{hint}"
        )
    return dist


def _is_path(spec: str) -> bool:
    return spec.endswith(".toml") or "/" in spec or "\\" in spec


def population_names() -> list[str]:
    """Names of the populations shipped with phri."""
    folder = resources.files("phri").joinpath("populations")
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def load_population(name_or_path: str | Path) -> Population:
    """A shipped population by name (``"default"``) or a population TOML file."""
    spec = str(name_or_path)
    if isinstance(name_or_path, Path) or _is_path(spec):
        path = Path(name_or_path)
        source = str(path)
        if not path.is_file():
            raise ConfigError(f"{source}: population file not found" if not path.exists() else
                              f"{source}: not a regular file, not a population file")  # fmt: skip
        raw, base_dir = path.read_bytes(), path.parent
    else:
        if spec not in population_names():
            raise UnknownNameError(
                f"population: unknown population '{spec}'; known: {', '.join(population_names())} "
                "(or give the path of a population .toml file)"
            )
        source = f"phri/populations/{spec}.toml"
        raw, base_dir = resources.files("phri").joinpath("populations", f"{spec}.toml").read_bytes(), None
    text = decode_utf8(
        raw,
        lambda line, offset, bad: ConfigError(
            f"{source}: not UTF-8 text (line {line}, byte {offset}: {bad!r}); "
            "save the population file as UTF-8"
        ),
    )
    return Population.from_dict(parse_toml(text, source, "a population file"), source, base_dir)


@functools.cache
def default_population() -> Population:
    """The population shipped with phri as ``default`` (calibrated to the CoRL 2017 study's cup and
    table tasks; its [about] table records how)."""
    return load_population("default")
