"""Features written in Python: pass one wherever a built-in feature's name is accepted.

A feature maps joint configurations to a number per configuration. phri evaluates it for all
points of a trajectory in one call (the waypoints q_1 … q_{N-1}, or ``samples`` points along each
segment), so write ``value`` (and ``gradient``) over a batch ``q`` of shape (M, n) with numpy::

    class CupOverTray(phri.Feature):
        name = "tray"

        def __init__(self, robot, tray_xy):
            self.robot, self.tray = robot, np.asarray(tray_xy)

        def value(self, q):  # (M, n) [rad] -> (M,)
            p = self.robot.frame_pose(self.robot.cup_frame, q)[:, :2, 3]
            return np.sum((p - self.tray) ** 2, axis=1)

        def gradient(self, q):  # (M, n) -> (M, n), d value / d q
            p = self.robot.frame_pose(self.robot.cup_frame, q)[:, :2, 3]
            jac = self.robot.jacobian(self.robot.cup_frame, q)[:, :2, :]
            return 2.0 * np.einsum("mc,mcj->mj", p - self.tray, jac)

    features = phri.Features(robot, ["efficiency", CupOverTray(robot, (0.4, 0.2))], scene=task.scene)

``Robot.frame_pose(frame, q)`` and ``Robot.jacobian(frame, q)`` take the whole (M, n) batch.
Without ``gradient``, phri takes central finite differences of ``value`` (one more call, 2·M·n
rows); without ``hessian`` (M, n, n), the optimiser takes finite differences of the gradient
when it asks for exact curvature, near the end of a solve; its first, convex phase takes no
curvature from the feature (see docs/features.md).

A feature that raises, returns the wrong shape or a non-finite value, or takes longer than its
``timeout`` [s] for one call, is a :class:`phri.exceptions.FeatureError` naming it; a
correction that the learner's worker thread learns from or replans for and that meets one is
rejected (the arm keeps its plan; a failed learning leaves the weights too) and recorded in the
history. The learner's worker calls the feature from its own thread, holding the GIL only
during the call.
"""

from __future__ import annotations

import importlib.util
import inspect
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from phri.exceptions import ConfigError

__all__ = ["Feature", "feature", "load_feature"]

Array = NDArray[np.float64]


class Feature:
    """Base class of a feature written in Python. Set ``name`` and define ``value``; ``gradient``
    and ``hessian`` are optional (see the module's documentation).

    Class attributes: ``name`` (unique in a feature set), ``samples`` (points per segment: 1 sums
    over the waypoints as the table and cup features do; more samples each segment at s = k/samples
    as the keep-outs do), ``timeout`` (the most one call may take [s]).
    """

    name: str = ""
    samples: int = 1
    timeout: float = 1.0
    gradient: Callable[[Array], Any] | None = None
    hessian: Callable[[Array], Any] | None = None

    def value(self, q: Array) -> Any:
        """The feature at each configuration: q (M, n) [rad] → (M,)."""
        raise NotImplementedError(f"{type(self).__name__} must define value(q)")

    def __repr__(self) -> str:
        return f"{type(self).__name__}(name={self.name!r})"


class _FunctionFeature(Feature):
    def __init__(
        self,
        name: str,
        value: Callable[[Array], Any],
        gradient: Callable[[Array], Any] | None,
        hessian: Callable[[Array], Any] | None,
        samples: int,
        timeout: float,
    ) -> None:
        self.name = name
        self._value = value
        self.gradient = gradient
        self.hessian = hessian
        self.samples = samples
        self.timeout = timeout

    def value(self, q: Array) -> Any:
        return self._value(q)


def feature(
    name: str,
    value: Callable[[Array], Any],
    gradient: Callable[[Array], Any] | None = None,
    *,
    hessian: Callable[[Array], Any] | None = None,
    samples: int = 1,
    timeout: float = 1.0,
) -> Feature:
    """A feature from functions: ``value(q)`` (M, n) → (M,), optionally ``gradient(q)`` (M, n) →
    (M, n) and ``hessian(q)`` (M, n) → (M, n, n); see :class:`Feature`."""
    if not isinstance(name, str) or not name:
        raise TypeError("name must be a non-empty string")
    if not callable(value):
        raise TypeError("value must be callable: value(q) with q of shape (M, n)")
    for arg, f in (("gradient", gradient), ("hessian", hessian)):
        if f is not None and not callable(f):
            raise TypeError(f"{arg} must be callable or None")
    return _FunctionFeature(name, value, gradient, hessian, samples, timeout)


def _module(source: str, path: Path) -> ModuleType:
    """The module in file `path` (loaded once per file and process)."""
    key = str(path.resolve())
    cached = _MODULES.get(key)
    if cached is not None:
        return cached
    spec = importlib.util.spec_from_file_location(f"phri_user_features_{len(_MODULES)}", path)
    if spec is None or spec.loader is None:
        raise ConfigError(f"source '{source}': cannot import {path}")
    module = importlib.util.module_from_spec(spec)
    # The file's folder first on the path while it runs, so that it can import its neighbours.
    sys.path.insert(0, str(path.parent))
    try:
        spec.loader.exec_module(module)
    except Exception as e:
        raise ConfigError(f"source '{source}': importing {path} raised {type(e).__name__}: {e}") from e
    finally:
        sys.path.remove(str(path.parent))
    _MODULES[key] = module
    return module


_MODULES: dict[str, ModuleType] = {}


def source_file(source: str, folder: Path) -> tuple[Path, str]:
    """The file and attribute a task file's ``source = "package.module:Name"`` names, looked up
    in `folder` (the task file's): ``folder/package/module.py`` (or ``.../module/__init__.py``).
    Only files under `folder` are imported: a task names its own code, never an installed module."""
    module, sep, attribute = source.partition(":")
    parts = module.split(".")
    if not sep or not attribute.isidentifier() or not all(p.isidentifier() for p in parts):
        raise ConfigError(f"source '{source}': must be 'module:Name' (e.g. 'mylab.features:CupOverTray')")
    base = folder.joinpath(*parts)
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.is_file():
            return path, attribute
    raise ConfigError(
        f"source '{source}': no module file {base.with_suffix('.py')} (modules are looked up in the task "
        "file's folder)"
    )


def load_feature(
    source: str, folder: Path, name: str, args: dict[str, Any], robot: Any, scene: Any
) -> Feature:
    """The feature a task file names by `source` (see :func:`source_file`): the module's attribute,
    an instance of :class:`Feature` as it is, or a class or function called with the table's
    ``args`` as keywords (and ``robot=``, ``scene=`` when it takes them). Its name is the task's
    key `name` (a feature object naming itself otherwise is an error)."""
    path, attribute = source_file(source, folder)
    module = _module(source, path)
    if not hasattr(module, attribute):
        raise ConfigError(f"source '{source}': {path} defines no '{attribute}'")
    obj = getattr(module, attribute)
    if not isinstance(obj, Feature):
        if not callable(obj):
            raise ConfigError(f"source '{source}': '{attribute}' is neither a phri.Feature nor callable")
        kwargs = dict(args)
        try:
            parameters = inspect.signature(obj).parameters
        except (TypeError, ValueError):
            parameters = {}  # type: ignore[assignment]
        for key, value in (("robot", robot), ("scene", scene)):
            if key in parameters and key not in kwargs:
                kwargs[key] = value
        try:
            obj = obj(**kwargs)
        except Exception as e:
            raise ConfigError(f"source '{source}': {attribute}(**args) raised {type(e).__name__}: {e}") from e
        if not isinstance(obj, Feature):
            raise ConfigError(
                f"source '{source}': {attribute}(...) returned {type(obj).__name__}, not a phri.Feature"
            )
    elif args:
        raise ConfigError(f"source '{source}': '{attribute}' is a feature object; it takes no args")
    if not obj.name:
        obj.name = name
    elif obj.name != name:
        raise ConfigError(
            f"source '{source}': the feature names itself '{obj.name}', but the task calls it '{name}'"
        )
    return obj
