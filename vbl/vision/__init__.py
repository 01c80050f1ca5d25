"""vbl.vision: pinhole camera and projected image features (pure JAX, float32).

Public API: :class:`CameraParams`, :func:`project_points` (``vbl.vision.camera``);
:func:`section2_features`, :func:`section3_features`, :class:`Section3Obs`,
:func:`flatten_section3`, :func:`check_inputs` and the ``SEC2_*`` / ``SEC3_*`` constants
(``vbl.vision.section2``, ``vbl.vision.section3``; the ball and goal images both build on:
``vbl.vision.projection``). See ``docs/vision.md``.
"""

from vbl.vision.camera import CameraParams, project_points
from vbl.vision.section2 import SEC2_DIM, check_inputs, section2_features
from vbl.vision.section3 import (
    SEC3_BALL_DIM,
    SEC3_GOAL_DIM,
    SEC3_OTHER_DIM,
    Section3Obs,
    flatten_section3,
    section3_features,
)

__all__ = ["CameraParams", "project_points", "section2_features", "section3_features",
           "Section3Obs", "flatten_section3", "check_inputs", "SEC2_DIM", "SEC3_BALL_DIM",
           "SEC3_GOAL_DIM", "SEC3_OTHER_DIM"]
