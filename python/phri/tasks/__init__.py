"""The shipped task files (``phri.load_task(name)``) and variations of any task (:func:`vary`)."""

from phri.tasks.variations import SECOND_FEATURE, vary

__all__ = ["SECOND_FEATURE", "vary"]
