"""Pixel-derived observations: the camera image, image noise, colour-blob features.

The analytic observation of a robot (:func:`vbl.vision.section3.section3_features`)
computes its Section 3 features from the projective geometry. The pixel observation
takes the paper's real pipeline instead (Sec 3.4.2): render the robot's camera image
(:func:`vbl.vision.render.render_camera`, at ``PixelObsParams.render``'s size), add image
noise to every pixel (``NoiseParams.pixel_std``, Gaussian on each colour channel in
[0, 1], then rounded to ``uint8`` as a frame grabber does), and extract the colour-blob
features (:func:`vbl.vision.blobs.section3_from_pixels`, same layout and units as the
analytic features). The ball centroid's eccentricity of the noise model (a property of
the ball, not of the image processing) is added to the pixel features as to the analytic
ones.

Lost sides: an image cannot show where a lost object is; the real robot kept it in its
tracking memory. The pixel observation has no memory, so it reports the side of the
camera's mid-plane where the object lies (the analytic features' rule), computed from the
world state. Reference: ``docs/render.md``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.envs.noise import NoiseParams, eccentric_centroid
from vbl.params import ParamError, section
from vbl.vision.blobs import BlobParams, section2_from_pixels, section3_from_pixels
from vbl.vision.camera import CameraParams, camera_frame, to_camera
from vbl.vision.fusion import stored_once
from vbl.vision.render import RenderParams, render_camera, to_uint8
from vbl.vision.section3 import Section3Obs, flatten_section3
from vbl.world.params import WorldParams
from vbl.world.physics import WorldState, goal_corners

__all__ = ["OBS_SOURCES", "PixelObsParams", "camera_image", "noisy_image", "lost_sides",
           "section3_from_image", "section3_pixels", "section2_from_image",
           "image_noise_shape", "check_obs_source"]

F32 = jnp.float32
#: Where an env's or a collection's features come from: the analytic camera, or the
#: rendered image through the colour-blob detector.
OBS_SOURCES = ("analytic", "pixels")


@struct.dataclass
class PixelObsParams:
    """Image size, drawing options and blob thresholds of pixel observations."""

    render: RenderParams = section(
        lambda: RenderParams(width=128, height=120),
        doc="camera image (size and drawing options); 128 x 120 keeps a pixel at 4 analytic "
            "px, the paper's 512 x 480 costs 16 times as much")
    blobs: BlobParams = section(BlobParams, doc="colour thresholds and goal-end rules")


def image_noise_shape(pix: PixelObsParams) -> tuple[int, int, int]:
    """Shape (H, W, 3) of the standard normals of one image's noise."""
    return (pix.render.height, pix.render.width, 3)


def camera_image(world: WorldState, me: int, cam: CameraParams, world_params: WorldParams,
                 robot_height, rp: RenderParams) -> jax.Array:
    """Robot ``me``'s (static int) camera image (rp.height, rp.width, 3) float32 RGB in
    [0, 1]; in a two-robot world the other robot ``1 - me`` is the box of the analytic
    Section 3 camera (length and width = the robot's diameter, height ``robot_height`` m;
    ignored with one robot)."""
    other, size = None, None
    if world.robots.shape[0] > 1:
        other = world.robots[1 - me]
        dia = 2 * jnp.asarray(world_params.robot.radius, F32)
        size = jnp.stack([dia, dia, jnp.asarray(robot_height, F32)])
    return render_camera(world.robots[me], world.ball, jnp.asarray(world_params.ball.radius, F32),
                         goal_corners(world_params), world_params.field, cam, rp, other, size)


def noisy_image(img: jax.Array, eps: jax.Array | None, pixel_std) -> jax.Array:
    """``img`` (H, W, 3) float in [0, 1] plus ``pixel_std * eps`` (``eps``: (H, W, 3)
    standard normals, or None: no noise), clipped and rounded to uint8."""
    if eps is None:
        return to_uint8(img)
    # the normals and the noisy image are each stored once (vbl.vision.fusion.stored_once):
    # otherwise XLA fuses the normals' transform and the ray casting into the consumers
    # that read a pixel's three channels, and each of them recomputes them
    eps = jnp.asarray(eps, F32)
    noisy = img + jnp.asarray(pixel_std, F32) * stored_once(eps)
    return to_uint8(stored_once(noisy))


def lost_sides(world: WorldState, me: int, cam: CameraParams, world_params: WorldParams,
               robot_height) -> jax.Array:
    """(2,) or, with two robots, (3,) float32: -1 / +1 for the ball, the goal (and the other
    robot): the side of robot ``me``'s camera mid-plane (X < 0 / >= 0) where the object's
    reference point lies (ball centre, goal mouth centre, the other robot's body centre)."""
    rb = jnp.asarray(world_params.ball.radius, F32)
    pts = [jnp.stack([world.ball[0], world.ball[1], rb]),
           goal_corners(world_params).mean(0).astype(F32)]
    if world.robots.shape[0] > 1:
        other = world.robots[1 - me]
        pts.append(jnp.stack([other[0], other[1], 0.5 * jnp.asarray(robot_height, F32)]))
    pts = jnp.stack(pts)
    x = to_camera(pts, camera_frame(world.robots[me], cam))[:, 0]
    return jnp.where(x < 0, -1.0, 1.0).astype(F32)


def section3_from_image(img: jax.Array, world: WorldState, me, cam: CameraParams,
                        world_params: WorldParams, noise: NoiseParams, robot_height, phase,
                        pix: PixelObsParams) -> jax.Array:
    """Section 3 features (26,) float32 (the layout of
    :func:`vbl.vision.section3.flatten_section3`) of robot ``me``'s camera image ``img``
    (H, W, 3) uint8: blob features, the lost sides of :func:`lost_sides`, then the ball
    centroid's eccentricity at rolling phase ``phase`` (rad)."""
    side = lost_sides(world, me, cam, world_params, robot_height)
    obs = section3_from_pixels(img, cam, pix.blobs, lost_side=side)
    ball = eccentric_centroid(obs.ball, obs.visible[0], phase, noise)
    return flatten_section3(Section3Obs(ball=ball, goal=obs.goal, other=obs.other,
                                        visible=obs.visible, lost_side=obs.lost_side))


def section3_pixels(world: WorldState, me, cam: CameraParams, world_params: WorldParams,
                    noise: NoiseParams, robot_height, phase, pix: PixelObsParams,
                    img_eps: jax.Array | None) -> jax.Array:
    """:func:`section3_from_image` of robot ``me``'s camera image, rendered, with
    ``noise.pixel_std`` image noise (``img_eps``: (H, W, 3) standard normals, None = no
    image noise)."""
    img = noisy_image(camera_image(world, me, cam, world_params, robot_height, pix.render),
                      img_eps, noise.pixel_std)
    return section3_from_image(img, world, me, cam, world_params, noise, robot_height, phase,
                               pix)


def section2_from_image(img: jax.Array, world: WorldState, cam: CameraParams,
                        world_params: WorldParams, pix: PixelObsParams) -> jax.Array:
    """Section 2 features (9,) float32 (layout ``SEC2_*``) of the one robot of ``world``
    from its camera image ``img`` (H, W, 3) uint8 (lost sides: :func:`lost_sides`)."""
    side = lost_sides(world, 0, cam, world_params, 0.0)
    return section2_from_pixels(img, cam, pix.blobs, lost_side=side)


def check_obs_source(obs_source: str, feature_noise: dict, image_noise: dict) -> None:
    """ParamError when a noise std of the other observation source is not 0:
    ``feature_noise`` ({path: std}) must be 0 with ``"pixels"`` (pixel features take their
    noise from the image), ``image_noise`` with ``"analytic"`` (no image to add it to)."""
    wrong = feature_noise if obs_source == "pixels" else image_noise
    for path, v in wrong.items():
        if np.any(np.asarray(v) != 0):
            why = ("pixel features take their noise from the image" if obs_source == "pixels"
                   else "the analytic features have no image")
            raise ParamError(f"{path}={v} must be 0 with obs_source={obs_source!r} ({why})")
