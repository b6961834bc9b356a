"""The errors of the study layer. Each is a :class:`phri.exceptions.ConfigError` (so a
:class:`~phri.exceptions.PhriError` and a :class:`ValueError`): catch the specific case, or all of them.
"""

from __future__ import annotations

from phri.exceptions import ConfigError, InvalidParameterError

__all__ = [
    "QuestionnaireError",
    "StudyConfigError",
    "StudyError",
    "StudyFileError",
    "StudyLockedError",
    "StudyMismatchError",
]


class StudyError(ConfigError):
    """Base class of the study's errors: a study folder or study description that cannot be used."""


class StudyConfigError(StudyError, InvalidParameterError):
    """A study parameter out of range (zero participants, unknown strategy, ...) or a study file
    (TOML) with a missing key or a wrong value; the message names the file, the key and what was expected."""


class StudyFileError(StudyError):
    """A file in a study folder that cannot be read (broken study.json, malformed results.csv, results
    without a manifest). Nothing in the folder is changed; the message names the file."""


class StudyMismatchError(StudyError):
    """The folder holds another study's results (its study.json differs from the study asked for).
    The message lists the differing parameters; nothing in the folder is changed."""


class StudyLockedError(StudyError):
    """Another process is running a study into the same folder."""


class QuestionnaireError(ConfigError):
    """A questionnaire answer or CSV that is not a valid Table 1 response (names file, row and column)."""
