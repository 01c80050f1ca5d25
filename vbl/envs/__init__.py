"""vbl.envs: tasks as gymnax-1.0-style functional environments on one base
(:class:`~vbl.envs.base.TaskEnv`), wrappers (macro actions: :mod:`vbl.envs.macro`), a brax
adapter, and the first-episode rollout and evaluation loops every learner uses
(:mod:`vbl.envs.rollout`).

Submodules are imported on use (``from vbl.envs.shooting import ShootingEnv``) so that
``import vbl.envs`` stays light.
"""

__all__ = ["TaskEnv", "NoiseOn", "ShootingEnv", "ShootingParams", "BraxAdapter",
           "MacroWrapper", "MacroActionParams"]


def __getattr__(name):
    if name in ("TaskEnv", "NoiseOn"):
        from vbl.envs import base
        return getattr(base, name)
    if name in ("ShootingEnv", "ShootingParams", "ShootingState", "ShootingStartParams"):
        from vbl.envs import shooting
        return getattr(shooting, name)
    if name in ("MacroWrapper", "MacroActionParams", "MacroEnvParams", "MacroState"):
        from vbl.envs import macro
        return getattr(macro, name)
    if name == "BraxAdapter":
        from vbl.envs.brax_adapter import BraxAdapter
        return BraxAdapter
    raise AttributeError(f"module 'vbl.envs' has no attribute {name!r}")
