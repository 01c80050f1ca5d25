"""The base of the task environments, in the mould of gymnax 1.0's ``Environment``.

:class:`TaskEnv` holds what :class:`~vbl.envs.shooting.ShootingEnv` and
:class:`~vbl.envs.shoot_pass.ShootPassEnv` share: the default parameters, ``reset``,
``step`` (auto-reset), ``step_env`` (no auto-reset), their observation-free forms
``reset_state`` / ``step_state``, ``get_obs`` (analytic or from pixels, by
``params.obs_source``), ``get_pixels`` (H, W, 3) uint8, the input checks (outside ``jit``)
and the random layout of a call (one hash per call, :func:`vbl.draws.draw_blocks`). A task
subclass gives only its parts: class keywords, its fresh episode (``_fresh``), one
transition (``_transition``), the draw blocks of its noise (``transition_blocks``) and what
its learner sees (``observer``, an :class:`Observer`). :class:`NoiseOn` holds the static
switches of the noise sources every task has (``slip``, ``pixel``); a source that is off
draws and computes nothing.

See docs/envs.md, "The task base" (a task's parts) and docs/world.md, "Random numbers".
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.draws import draw_blocks, normals
from vbl.envs.checks import check_action_index
from vbl.envs.pixels import noisy_image
from vbl.params import ParamError, param, validate

__all__ = ["NoiseOn", "Observer", "TaskEnv", "is_traced"]


def is_traced(tree: Any) -> bool:
    """True when a leaf of ``tree`` is a jax tracer (inside ``jit``/``vmap``)."""
    return any(isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves(tree))


@dataclasses.dataclass(frozen=True)
class Observer:
    """What a task's learner sees of a state, for given parameters: the observation from the
    analytic camera, the camera image and the observation from that image.

    Attributes:
      features: ``(state, eps) -> obs``, the analytic camera's observation; ``eps`` the
        pixel noise's standard normals, (pixel_noise_dim,) float32, or None (no noise).
      image: ``state -> (H, W, 3)`` float32 RGB in [0, 1], the learner's camera image.
      from_image: ``(img, state) -> obs``, the observation from ``img``, (H, W, 3) uint8.
      image_noise_std: the std of the image noise (in [0, 1] intensity units).
    """

    features: Callable[[Any, jax.Array | None], jax.Array]
    image: Callable[[Any], jax.Array]
    from_image: Callable[[jax.Array, Any], jax.Array]
    image_noise_std: Any = 0.0


@struct.dataclass
class NoiseOn:
    """Static switches of the noise sources every task has (module docstring); each task's
    ``check`` names the stds a switch governs."""

    slip: bool = param(False, doc="tire slip is drawn (the task's slip stds, e.g. "
                       "world.robot.slip_std; off: they must be 0)", static=True)
    pixel: bool = param(False, doc="pixel noise is drawn (the task's pixel noise stds, e.g. "
                        "the cameras' pixel_noise_std; off: they must be 0)", static=True)


class TaskEnv:
    """Functional task environment: the shared construction, reset, step and checks (module
    docstring). A subclass declares its types and sizes as class keywords::

        class MyEnv(TaskEnv, params=MyParams, state=MyState, fresh_words=5,
                    pixel_noise_dim=SEC2_NOISE_DIM, option=("kind", ("a", "b"))): ...

    Args (of a task's constructor): its static option (one of the declared choices, kept
    as ``choice``; the task sets its own name for it before calling this constructor) and
    ``params``, the default parameters (validated; ``None`` uses the defaults).
    """

    params_type: type
    state_type: type
    fresh_words: int
    pixel_noise_dim: int
    option: str
    choices: tuple[str, ...]
    name: str
    num_actions: int
    action_labels: tuple[str, ...]
    observation_shape: tuple[int, ...]

    def __init_subclass__(cls, *, params: type, state: type, fresh_words: int,
                          pixel_noise_dim: int, option: tuple[str, tuple[str, ...]], **kw):
        super().__init_subclass__(**kw)
        cls.params_type, cls.state_type = params, state
        cls.fresh_words, cls.pixel_noise_dim = fresh_words, pixel_noise_dim
        cls.option, cls.choices = option[0], tuple(option[1])

    def __init__(self, choice: str, params: Any = None):
        if choice not in self.choices:
            raise ValueError(f"{self.option}={choice!r} is not allowed; choose one of "
                             f"{list(self.choices)}")
        self.choice = choice  #: the static option's value (a task also names it)
        self._default_params = self.validate(self.defaults() if params is None else params)

    # ------------------------------------------------------------------ task parts
    def defaults(self) -> Any:
        """The default parameters of this env (its constructor's ``params=None``)."""
        return self.params_type()

    def transition_blocks(self, params: Any) -> tuple[tuple[int, bool], ...]:
        raise NotImplementedError

    def _fresh(self, words: jax.Array, params: Any) -> Any:
        raise NotImplementedError

    def _transition(self, eps: tuple, state: Any, action: jax.Array, params: Any):
        raise NotImplementedError

    def observer(self, params: Any) -> Observer:
        """How the learner sees a state under ``params`` (:class:`Observer`)."""
        raise NotImplementedError

    def check_params(self, params: Any) -> None:
        """Consistency rules of this env beyond the parameters' own (none by default)."""

    # ------------------------------------------------------------------ observations
    def image_shape(self, params: Any = None) -> tuple[int, int, int]:
        """(H, W, 3): the shape of :meth:`get_pixels`'s image."""
        rp = (self._default_params if params is None else params).pixels.render
        return (rp.height, rp.width, 3)

    def pixel_noise_size(self, params: Any) -> int:
        """Standard normals of one observation's pixel noise: ``pixel_noise_dim``, or one per
        colour channel of each pixel under ``obs_source="pixels"``."""
        if params.obs_source == "pixels":
            return int(np.prod(self.image_shape(params)))
        return self.pixel_noise_dim

    def get_pixels(self, state: Any, params: Any, eps: jax.Array | None = None) -> jax.Array:
        """The learner's camera image (H, W, 3) uint8; ``eps``: the pixel noise's normals
        (image noise only under ``obs_source="pixels"``; None: none)."""
        shape = self.image_shape(params)
        img_eps = None if eps is None or params.obs_source != "pixels" else eps.reshape(shape)
        observer = self.observer(params)
        return noisy_image(observer.image(state), img_eps, observer.image_noise_std)

    def get_obs(self, state: Any, params: Any, eps: jax.Array | None = None) -> jax.Array:
        """The observation of ``state`` (module docstring, "Observation source"); ``eps``:
        the pixel noise's standard normals, or None (``noise_on.pixel`` off)."""
        if params.obs_source == "pixels":
            return self.observer(params).from_image(self.get_pixels(state, params, eps), state)
        return self.observer(params).features(state, eps)

    # ------------------------------------------------------------------ metadata
    @property
    def default_params(self) -> Any:
        return self._default_params

    def __repr__(self) -> str:
        fields = [f.name for f in dataclasses.fields(self.params_type)]
        return (f"{type(self).__name__}({self.option}={self.choice!r}, "
                f"params={fields})")

    # ------------------------------------------------------------------ checks
    def validate(self, params: Any) -> Any:
        """Check parameter types, bounds and consistency; raise ParamError. Returns params."""
        if not isinstance(params, self.params_type):
            raise ParamError(f"params must be {self.params_type.__name__}, got "
                             f"{type(params).__name__}")
        validate(params)  # fields and every section's check() rule
        self.check_params(params)
        return params

    def check_action(self, action: Any) -> None:
        """Raise ValueError unless ``action`` is a () integer in [0, num_actions)."""
        check_action_index(action, self.num_actions, self.name, self.action_labels)

    def _check_state(self, state: Any) -> None:
        if not isinstance(state, self.state_type):
            raise ValueError(f"state must be {self.state_type.__name__}, got "
                             f"{type(state).__name__}")
        robots, ball = np.shape(state.world.robots), np.shape(state.world.ball)
        n = len(self._default_params.world.robot_kinds)
        if robots != (n, 3) or ball != (2,):
            raise ValueError(f"state has robots {robots} / ball {ball}; expected "
                             f"({n}, 3) / (2,) (one env; vmap for a batch)")

    def _check_inputs(self, state: Any, action: Any, params: Any) -> None:
        if not is_traced((action, state)):
            self.check_action(action)
            self._check_state(state)
        if not is_traced(params):
            self.validate(params)

    # ------------------------------------------------------------------ random layout
    def _draw(self, key: jax.Array, params: Any, transition: bool, fresh: bool):
        """One hash of ``key``: the transition's normals (a tuple, one per transition block;
        empty without ``transition``), the fresh episode's words (None without ``fresh``)
        and the pixel noise's normals (None when ``noise_on.pixel`` is off)."""
        blocks = self.transition_blocks(params) if transition else ()
        *eps, words, pixel = draw_blocks(
            key, *blocks, (self.fresh_words if fresh else 0, fresh),
            (self.pixel_noise_size(params), params.noise_on.pixel))
        return tuple(normals(e) for e in eps), words, normals(pixel)

    # ------------------------------------------------------------------ reset and step
    def reset_state(self, key: jax.Array, params: Any = None) -> tuple[Any, jax.Array | None]:
        """:meth:`reset` without the observation: (state, eps), where ``get_obs(state,
        params, eps)`` is the obs :meth:`reset` returns (``eps``: the pixel noise's standard
        normals, None when off). A loop that observes inside its body
        (:func:`vbl.agents.cva_state.collect`, the brax adapter) then holds the camera once
        in its compiled program."""
        params = self._default_params if params is None else params
        if not is_traced(params):
            self.validate(params)
        _, words, pixel = self._draw(key, params, transition=False, fresh=True)
        return self._fresh(words, params), pixel

    def reset(self, key: jax.Array, params: Any = None) -> tuple[jax.Array, Any]:
        """Fresh episode: (obs, state)."""
        params = self._default_params if params is None else params
        state, eps = self.reset_state(key, params)
        return self.get_obs(state, params, eps), state

    def step_env(self, key: jax.Array, state: Any, action: jax.Array, params: Any = None):
        """One primitive without auto-reset: (obs, state, reward, terminated, truncated, info)."""
        params = self._default_params if params is None else params
        self._check_inputs(state, action, params)
        eps, _, pixel = self._draw(key, params, transition=True, fresh=False)
        state, reward, terminated, truncated, info = self._transition(eps, state, action,
                                                                      params)
        return self.get_obs(state, params, pixel), state, reward, terminated, truncated, info

    def step_state(self, key: jax.Array, state: Any, action: jax.Array, params: Any = None):
        """:meth:`step` without the observation: (state, eps, reward, terminated,
        truncated, info), where ``get_obs(state, params, eps)`` is the obs :meth:`step`
        returns (see :meth:`reset_state`). The auto-reset selects the state, so the
        observation is computed once, from the selected state."""
        params = self._default_params if params is None else params
        self._check_inputs(state, action, params)
        eps, words, pixel = self._draw(key, params, transition=True, fresh=True)
        nstate, reward, terminated, truncated, info = self._transition(eps, state, action,
                                                                      params)
        done = info["episode_done"]
        fresh = self._fresh(words, params)
        nstate = jax.tree_util.tree_map(lambda a, b: jnp.where(done, a, b), fresh, nstate)
        return nstate, pixel, reward, terminated, truncated, info

    def step(self, key: jax.Array, state: Any, action: jax.Array, params: Any = None):
        """One primitive with auto-reset (a fresh episode when this one ended).

        Returns (obs, state, reward () float32, terminated () bool, truncated () bool,
        info); obs/state are the new episode's after a reset, while
        reward/terminated/truncated/info describe the finished step.
        """
        params = self._default_params if params is None else params
        nstate, eps, reward, terminated, truncated, info = self.step_state(key, state, action,
                                                                          params)
        return self.get_obs(nstate, params, eps), nstate, reward, terminated, truncated, info
