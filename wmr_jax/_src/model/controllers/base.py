"""Controllers as values: a pure command law, its parameter type and a registry by name.

The rest of the package asks a ``Controller``, never which one it is.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import re
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from wmr_jax._src.checks import (
    as_float_tree,
    as_pose_array,
    check_bool,
    described,
    float_dtype,
    is_traced,
    real_array,
)


class Pluggable:
    """What a controller and an estimator share: a name, a parameter class and its defaults."""

    KIND: ClassVar[str]
    name: str
    params_type: type

    def check_params_type(self) -> None:
        if not isinstance(self.params_type, type):
            raise ValueError(
                f"{self.KIND} {self.name!r}: {self.KIND}.params_type = "
                f"{described(self.params_type):.60} is not allowed; allowed: a class (its "
                "defaults are the default parameters)"
            )

    def __repr__(self) -> str:
        # The generated repr would bury a rollout's signature in help().
        return f"<{self.KIND.title()} {self.name!r}>"

    def validated(self, params: Any) -> Any:
        """Return ``validate(params)``, refused in one line unless it returns parameters."""
        checked = self.validate(params)
        if not isinstance(checked, self.params_type):
            raise ValueError(
                f"{self.KIND} {self.name!r}: {self.KIND}.validate(params) returned "
                f"{described(checked):.60}; allowed: the parameters it checked "
                "(validate(params) -> params)"
            )
        if not (getattr(self.validate, "__module__", None) or "").startswith("wmr_jax."):
            # A validate of one's own may let a bool or a string through, which NumPy
            # would read as 1.0 or 3.0: every concrete leaf must be real numbers.
            allowed = "real numbers (no bools or strings; a flag is a static field)"
            for path, leaf in jax.tree_util.tree_leaves_with_path(checked):
                if isinstance(leaf, jax.core.Tracer):
                    continue  # no value to check under a transformation
                where = f"{self.KIND} {self.name!r}: params{jax.tree_util.keystr(path)}"
                if not isinstance(leaf, jax.Array):
                    real_array(where, leaf, allowed)
                elif leaf.dtype.kind not in "iuf":  # its dtype: no copy from the device
                    raise ValueError(
                        f"{where} = {described(leaf)} is not allowed; allowed: {allowed}"
                    )
        return checked

    def default_params(self) -> Any:
        """Return the default parameters: ``params_type()``."""
        try:
            return self.params_type()
        except TypeError as err:
            raise ValueError(
                f"{self.KIND} {self.name!r}: {self.KIND}.params_type() raised TypeError: {err}; "
                "allowed: a class whose every field has a default (the default parameters)"
            ) from None


@dataclasses.dataclass(frozen=True, repr=False)
class Controller(Pluggable):
    """A pose controller as a value (hashable, so it can be a static ``jit`` argument).

    Attributes:
        name: short name used by the CLI and in tables.
        command: ``(pose (…,3), ref (…,3), params, *, temperature, frame) -> (v, ω)``;
            ``frame``, when given, is the pose as ``(x, y, cos θ, sin θ)``.
        params_type: the class of its parameter pytree (its defaults the default).
        validate: checks a parameter pytree before tracing; returns it.
        region: ``(pose, ref, params, *, frame) -> int32`` diagnostic label, or
            ``None`` for a controller without regions (labels are then −1).
        smooth: whether ``command`` accepts a positive ``temperature``.
        check_robot: ``(params, robot) -> None`` before a rollout, to warn
            about parameters unsuited to the robot; or ``None``.
        check_sampling: ``(params, dt) -> None``, likewise for the period; or ``None``.
    """

    KIND = "controller"
    name: str
    command: Callable[..., tuple[jax.Array, jax.Array]]
    params_type: type
    validate: Callable[[Any], Any]
    region: Callable[..., jax.Array] | None = None
    smooth: bool = False
    check_robot: Callable[[Any, Any], None] | None = None
    check_sampling: Callable[[Any, Any], None] | None = None

    def __post_init__(self) -> None:
        # Checked here: a controller is usable without registering.
        if not isinstance(self.name, str) or not self.name.strip():
            raise ValueError(
                f"controller.name = {self.name!r} is not allowed; allowed: a non-empty str"
            )
        check_bool("controller.smooth", self.smooth)  # "no" would be true
        for field in _CALLS:
            value = getattr(self, field)
            if not callable(value) and not (value is None and field not in _REQUIRED):
                allowed = "a function" if field in _REQUIRED else "a function, or None"
                raise ValueError(
                    f"controller {self.name!r}: controller.{field} = {described(value):.60} is not "
                    f"allowed; allowed: {allowed} {_CALLS[field][2]}"
                )
            _check_signature(self.name, field, value)
        self.check_params_type()

    @property
    def own(self) -> bool:
        """Whether the law is the package's own (trusted: not traced to check it)."""
        return (getattr(self.command, "__module__", None) or "").startswith("wmr_jax.")

    def checked(self, params: Any) -> Any:
        """Return ``validate(params)``; refuse a non-pytree, and a ``validate`` that loses them."""
        require_pytree(f"controller {self.name!r}", params)
        return self.validated(params)

    def finite_allowed(self, allowed: str) -> str:
        """``allowed`` of a refused non-finite run, naming a law of one's own as a cause."""
        return allowed if self.own else f"{allowed}, and commands of {self.name!r} that stay finite"

    def region_of(
        self, pose: jax.Array, ref: jax.Array, params: Any, *, frame: Any = None
    ) -> jax.Array:
        """Return the region label of the command at ``pose`` (−1 if it has none)."""
        if self.region is None:
            shape = jnp.shape(frame[0]) if frame is not None else jnp.shape(pose)[:-1]
            return jnp.full(shape, -1, jnp.int32)
        return self.region(pose, ref, params, frame=frame)


# How the package calls each function of a Controller: the positional
# arguments, then each set of keywords it passes (the rollouts pass frame= to
# command, the waypoint loops do not), and the signature shown as allowed.
_CALLS: dict[str, tuple[tuple[str, ...], tuple[tuple[str, ...], ...], str]] = {
    "command": (
        ("pose", "ref", "params"),
        (("temperature",), ("temperature", "frame")),
        "command(pose, ref, params, *, temperature=None, frame=None) -> (v, omega)",
    ),
    "validate": (("params",), ((),), "validate(params) -> params"),
    "region": (("pose", "ref", "params"), (("frame",),), "region(pose, ref, params, *, frame)"),
    "check_robot": (("params", "robot"), ((),), "check_robot(params, robot) -> None"),
    "check_sampling": (("params", "dt"), ((),), "check_sampling(params, dt) -> None"),
}


_REQUIRED = ("command", "validate")  # the rest may be None


def _check_signature(name: Any, field: str, function: Any) -> None:
    """Refuse a ``Controller`` function the package cannot call; an unreadable signature passes."""
    if not callable(function):
        return
    try:
        signature = inspect.signature(function)
    except (TypeError, ValueError):
        return
    positional, keyword_sets, allowed = _CALLS[field]
    for keywords in keyword_sets:
        try:
            signature.bind(*positional, **dict.fromkeys(keywords))
        except TypeError as err:
            shown = getattr(function, "__qualname__", type(function).__name__)
            raise ValueError(
                f"controller {name!r}: controller.{field} = {shown}{signature} is not allowed "
                f"({err}); allowed: a function {allowed} (keywords with defaults, or **kwargs)"
            ) from None


def check_command_output(controller: Controller, params: Any) -> None:
    """Refuse a command law that does not return two real scalars ``(v, ω)`` for one pose.

    Traced abstractly (``jax.eval_shape``), once per parameter structure and
    dtype; the package's own laws are trusted.
    """
    if controller.own:
        return
    if any(np.ndim(leaf) != 0 for leaf in jax.tree.leaves(params)):
        params = controller.default_params()
    _check_output_once(controller, jax.tree.structure(params), np.dtype(float_dtype()).name)


@functools.lru_cache(maxsize=64)
def _check_output_once(controller: Controller, structure: Any, dtype: str) -> None:
    """``check_command_output`` for one parameter structure and dtype (refusals are not kept)."""
    probe = jax.tree.unflatten(structure, [jax.ShapeDtypeStruct((), dtype)] * structure.num_leaves)
    pose = jax.ShapeDtypeStruct((3,), dtype)
    allowed = "allowed: (v, omega), two real scalars for one pose (3,) (docs/custom_controller.md)"
    shown = f"controller {controller.name!r}: controller.command(pose (3,), ref (3,), params)"
    try:
        out = jax.eval_shape(
            lambda p, r, g: controller.command(p, r, g, temperature=None), pose, pose, probe
        )
    except Exception as err:  # any error of the law, reported in one line
        raise call_error(shown, controller.command, err, allowed) from None
    if not isinstance(out, (tuple, list)) or len(out) != 2:
        what = f"{len(out)} values" if isinstance(out, (tuple, list)) else type(out).__name__
        if isinstance(out, jax.ShapeDtypeStruct):
            what = f"one array of shape {out.shape} of {out.dtype}"
        raise ValueError(f"{shown} returned {what}; {allowed}")
    for name, value in zip(("v", "omega"), out, strict=True):
        shape, kind = getattr(value, "shape", None), np.dtype(getattr(value, "dtype", object)).kind
        if shape != () or kind != "f":
            got = f"shape {shape} of {getattr(value, 'dtype', type(value).__name__)}"
            raise ValueError(f"{shown} returned {name} of {got}; {allowed}")


def call_error(shown: str, function: Callable, err: Exception, allowed: str) -> ValueError:
    """One line for an error of a user's ``function`` traced abstractly: where, and what to do."""
    where = f"{shown} raised {type(err).__name__}{_where(function, err)}"
    if isinstance(err, jax.errors.ConcretizationTypeError):  # TracerBoolConversionError too
        return ValueError(
            f"{where}: it asks the value of a traced array (a Python if, bool(), float() or "
            "int() of one); allowed: jnp.where or jax.lax.cond, as it is traced by jit, vmap "
            "and grad (docs/custom_controller.md)"
        )
    return ValueError(f"{where}: {' '.join(str(err).split())[:240]}; {allowed}")


def require_pytree(owner: str, params: Any) -> None:
    """Refuse parameters JAX cannot see into: a class not registered as a pytree."""
    leaves = jax.tree.leaves(params)
    if len(leaves) == 1 and leaves[0] is params:
        raise ValueError(
            f"{owner}: its parameters {type(params).__name__} are not a pytree; allowed: a "
            "dataclass registered with jax.tree_util.register_dataclass "
            "(docs/custom_controller.md)"
        )


def _where(function: Callable, err: BaseException) -> str:
    """`` at FILE:LINE``, the last line of ``function``'s file that ``err`` passed; or ``""``."""
    code = getattr(function, "__code__", None)
    if code is None:
        return ""
    frames = traceback.walk_tb(err.__traceback__)
    lines = [line for frame, line in frames if frame.f_code.co_filename == code.co_filename]
    return f" at {Path(code.co_filename).name}:{lines[-1]}" if lines else ""


_REGISTRY: dict[str, Controller] = {}
_NAME = re.compile(r"[a-z0-9][a-z0-9_-]*")  # a CLI word, and safe in a file name


def check_registry_name(kind: str, name: Any) -> str:
    """Return ``name`` if a registry may hold it (a CLI word); refuse it naming ``kind``."""
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        raise ValueError(
            f"{kind}.name = {name!r} is not allowed; allowed: lower-case letters, digits, "
            "'-' and '_', starting with a letter or digit"
        )
    return name


def register_controller(controller: Controller, *, replace: bool = False) -> Controller:
    """Make ``controller`` known by name to the CLI and ``get_controller``.

    Args:
        controller: the controller; its name lower-case letters, digits,
            ``-`` and ``_`` (a CLI word and part of file names).
        replace: allow a name already registered to another controller.
    """
    if not isinstance(controller, Controller):
        raise ValueError(
            f"controller is a {type(controller).__name__}; allowed: a wmr_jax.Controller"
        )
    replace = check_bool("replace", replace)
    name = check_registry_name("controller", controller.name)
    known = _REGISTRY.get(name)
    if known is not None and known != controller and not replace:
        raise ValueError(
            f"controller.name = {name!r} is registered already; allowed: another name, or "
            "replace=True"
        )
    _REGISTRY[name] = controller
    return controller


def registered_names() -> list[str]:
    """Return the names of the registered controllers, in registration order."""
    return list(_REGISTRY)


def get_controller(name: str | Controller) -> Controller:
    """Return the controller called ``name`` (a ``Controller`` is returned as is)."""
    if isinstance(name, Controller):
        return name
    try:
        return _REGISTRY[name]
    except (KeyError, TypeError):
        raise ValueError(
            f"controller = {name!r} is not known; allowed: {sorted(_REGISTRY)}"
        ) from None


def controller_names(names: Any) -> list[str]:
    """Return the registered names a study runs, checked before any runs.

    ``names``: registered names or ``Controller`` values, one alone, or ``None`` for all.
    """
    if names is None:
        return registered_names()
    if isinstance(names, (str, Controller)):
        names = [names]
    out = []
    for name in names:
        controller = get_controller(name)
        if _REGISTRY.get(controller.name) != controller:
            raise ValueError(
                f"controller {controller.name!r} is not registered; allowed: a registered "
                "controller (wmr_jax.register_controller)"
            )
        out.append(controller.name)
    if not out:
        raise ValueError("controller_names = [] is not allowed; allowed: at least one controller")
    return out


def check_law_inputs(
    pose: Any, ref: Any, params: Any, params_type: type, validate: Callable[[Any], Any]
) -> tuple[Any, Any, Any]:
    """Check the arguments of a law's entry point (``control``; traced ones pass).

    ``pose`` and ``ref`` poses ``(..., 3)`` that broadcast, ``params`` a
    ``params_type`` that ``validate`` accepts.
    """
    pose, ref = as_pose_array("pose", pose), as_pose_array("ref", ref)
    if not _broadcasts(np.shape(pose)[:-1], np.shape(ref)[:-1]):
        raise ValueError(
            f"pose has batch shape {np.shape(pose)[:-1]} and ref {np.shape(ref)[:-1]}; "
            "allowed: shapes that broadcast"
        )
    if not isinstance(params, params_type):
        raise ValueError(
            f"gains = {params!r} is not allowed; allowed: a wmr_jax.{params_type.__name__}"
        )
    if is_traced(params):
        return pose, ref, params
    params = as_float_tree(validate(params))
    batch = np.broadcast_shapes(np.shape(pose)[:-1], np.shape(ref)[:-1])
    shapes = {np.shape(leaf) for leaf in jax.tree.leaves(params)}
    if not _broadcasts(batch, *shapes):
        shown = next((s for s in shapes if not _broadcasts(batch, s)), max(shapes, key=len))
        raise ValueError(
            f"gains have batch shape {shown} and the poses {batch}; "
            "allowed: shapes that broadcast (one gain per pose, or one for all)"
        )
    return pose, ref, params


def _broadcasts(*shapes: tuple[int, ...]) -> bool:
    try:
        np.broadcast_shapes(*shapes)
    except ValueError:
        return False
    return True
