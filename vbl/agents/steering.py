"""A hand-written steering policy for the shooting task: the reference of what a
memoryless policy on the Section-2 features achieves (Figure 9 evaluates it on the same
starts as its learner).

Ball in view: FL / F / FR as the ball's image position x2 is left of ``-band`` / within
``band`` / right of ``+band``; ball lost: TL / TR towards the side where it left the image.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from vbl.vision.section2 import SEC2_BALL_LOST_SIDE, SEC2_BALL_POS, SEC2_BALL_VISIBLE

__all__ = ["steer_action"]


def steer_action(obs: jax.Array, band: Any, labels: tuple[str, ...]) -> jax.Array:
    """Primitive index (int32 ()) for raw Section-2 features ``obs``; ``band`` in px;
    ``labels`` the robot's primitive names (must hold FL, F, FR, TL, TR)."""
    x2 = obs[SEC2_BALL_POS]
    seen = jnp.where(x2 > band, labels.index("FR"),
                     jnp.where(x2 < -band, labels.index("FL"), labels.index("F")))
    lost = jnp.where(obs[SEC2_BALL_LOST_SIDE] > 0, labels.index("TR"), labels.index("TL"))
    return jnp.where(obs[SEC2_BALL_VISIBLE] > 0.5, seen, lost).astype(jnp.int32)
