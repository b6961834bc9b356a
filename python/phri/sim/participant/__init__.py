"""The simulated study participant (see docs/participant.md): a person who was shown the desired
behaviour and pushes the robot towards it with minimal intervention.

One concept per module:

- :mod:`~phri.sim.participant.parameters`: every parameter's SI unit, meaning and range;
- :mod:`~phri.sim.participant.params`: one person (:class:`ParticipantParams`), and practice
  between attempts (:meth:`ParticipantParams.for_attempt`);
- :mod:`~phri.sim.participant.perception`: what they see — the task's features against the desired
  behaviour, and the move of the cup that fixes them;
- :mod:`~phri.sim.participant.arm`: how hard they push — a compliant human arm;
- :mod:`~phri.sim.participant.persistence`: when they push, pause, re-try and give up;
- :mod:`~phri.sim.participant.model`: the person (:class:`Participant`), called every control tick;
- :mod:`~phri.sim.participant.population`: people differ — a distribution per parameter, from a
  TOML file (the default one ships with phri).
"""

from phri.sim.participant.model import Participant
from phri.sim.participant.parameters import PARAMETERS
from phri.sim.participant.params import ParticipantParams
from phri.sim.participant.population import (
    Population,
    default_population,
    load_population,
    population_names,
)

__all__ = [
    "PARAMETERS",
    "Participant",
    "ParticipantParams",
    "Population",
    "default_population",
    "load_population",
    "population_names",
]
