"""Episode videos of a run folder's policy: ``vbl render`` (docs/render.md, "Videos").

A frame shows, side by side, the learner's camera image and the top view of the field
(:func:`vbl.vision.render.render_world`) and a panel with the learner's discrete state (a
cell in a grid of all states), its state vector (bars: the CVA state of Table 2, the
Section 2 features of the grid learner) and the primitive in force (boxes, one per
primitive); a caption names the episode, the time, the state index and the action.

* **Policies.** ``learned``: the final Q table of one learner of the run (one sweep point,
  one seed), restored from the run folder's last checkpoint (``checkpoints/``, which every
  ``vbl run`` writes at the end of a run; a shard's folder, ``vbl run --shard``, holds
  its own learners' and renders them; a merged run, ``vbl merge``, keeps none and names
  the shard folder to render instead), on the learner's own state space (grid cells;
  CVA models and codebooks). ``random``: the all-zero table with random tie-breaking in the
  same action space (the ``random_success`` policy of the programs); it needs no
  checkpoint (a CVA learner's models and codebooks are rebuilt from the run's config and
  the learner's key, as its run built them).
* **Rollout.** The learner's env under its macro-action wrapper
  (:class:`vbl.envs.macro.MacroWrapper`, as the Q runner steps it), ``episodes`` fresh
  starts in parallel (``vmap``), each a ``lax.scan`` of ``max_steps`` steps; a frame per
  primitive of the first episode (steps after it ended are dropped). Actions are
  epsilon-greedy on the table: the evaluation epsilon of the experiment (grid:
  ``train.eval_epsilon``, near-greedy; Table 2: 0, greedy).
* **Frames** are rendered in JAX, ``vmap`` over time steps in batches (``lax.map``); only
  the caption text (Pillow) and the file writing (imageio: GIF, or MP4 through
  imageio-ffmpeg) loop over frames.

Which experiments render: :data:`RENDERABLE`.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.agents.exploration import select_action
from vbl.agents.state_maps import CVAMap
from vbl.engine.checkpoint import Checkpoints
from vbl.engine.errors import EngineError
from vbl.engine.jax_setup import engine_precision
from vbl.engine.rebuild import load_run
from vbl.engine.sweep import Shard, make_plan
from vbl.envs.macro import MacroWrapper, macro_env_params
from vbl.envs.shooting import ShootingEnv
from vbl.params import param, validate
from vbl.programs.table2 import table2_env
from vbl.programs.tabular import PREPARE_STREAM
from vbl.spaces.grid import NUM_GOAL_STATES, NUM_GRID_STATES, grid_state
from vbl.spaces.macro_action import stop_key
from vbl.vision.render import RenderParams, render_world, to_uint8

__all__ = ["VideoParams", "Policy", "RENDERABLE", "POLICIES", "EXTENSIONS", "load_policy",
           "trajectories", "render_frames", "write_video", "render_run", "Video"]

F32 = jnp.float32
POLICIES = ("learned", "random")
EXTENSIONS = (".gif", ".mp4")
PAPER_WIDTH, PAPER_HEIGHT = 512, 480  #: the paper's camera image (its aspect ratio is kept)
TOP_WIDTH, TOP_HEIGHT = 320, 192      #: the top view's aspect ratio (RenderParams defaults)

PANEL_BG = (0.12, 0.12, 0.14)     #: info panel background
CELL_RGB = (0.35, 0.35, 0.40)     #: state grid: a cell
STATE_RGB = (1.0, 0.85, 0.1)      #: state grid: the current state's cell
BAR_POS_RGB = (0.3, 0.75, 1.0)    #: a positive state component
BAR_NEG_RGB = (1.0, 0.45, 0.3)    #: a negative state component
ACTION_RGB = (0.3, 0.9, 0.4)      #: the primitive in force
ACTION_OFF_RGB = (0.3, 0.3, 0.33)  #: the other primitives
CAPTION_RGB = (255, 255, 255)     #: caption text
MP4_BLOCK = 2  #: an MP4's width and height are padded to a multiple of this (H.264, yuv420p)


@struct.dataclass
class VideoParams:
    """Size, length and speed of a ``vbl render`` video."""

    height: int = param(128, doc="frame height; the camera image keeps the paper's 512 x 480 "
                        "aspect and the top view its 320 x 192 one", unit="px", static=True,
                        ge=32, le=960)
    max_steps: int = param(200, doc="most primitives (frames) shown per episode", unit="step",
                           static=True, ge=1)
    fps: float = param(10.0, doc="frames per second of the file (10: real time, one "
                       "0.1 s primitive per frame)", gt=0.0, le=100.0)
    batch: int = param(32, doc="frames rendered per vmapped batch (memory: about 80 bytes "
                       "per pixel of a batch)", static=True, ge=1)
    panel_frac: float = param(0.6, doc="width of the info panel as a fraction of the frame "
                              "height", gt=0.0, le=2.0)
    caption: int = param(14, doc="height of the caption strip under the images (episode, "
                         "time, state, action: no two frames are alike, so a GIF keeps every "
                         "frame)", unit="px", static=True, ge=10, le=40)


class Policy(NamedTuple):
    """Everything a rollout and its frames need (built by :func:`load_policy`)."""

    env: Any                 #: gymnax-style env (auto-reset) the learner acts in
    env_params: Any
    state_fn: Callable       #: obs -> int32 discrete state
    perceive_fn: Callable    #: obs -> int32 what the map perceives (ends a macro action)
    vector_fn: Callable      #: obs -> (d,) float32 state vector shown as bars
    macro: Any               #: MacroActionParams of the learner
    discount: float
    q: jax.Array             #: (S, A) float32 (zeros: the random policy)
    epsilon: float
    world: Any               #: WorldParams of the env
    camera_fn: Callable      #: env_params -> CameraParams of the learner
    me_fn: Callable          #: env_params -> () int32 the learner's robot index
    labels: tuple[str, ...]  #: primitive names
    grid_cols: int           #: columns of the state grid panel
    title: str               #: what is shown (experiment, point, seed, policy)


def _find_world(state: Any) -> Any:
    """The ``WorldState`` inside nested wrapper states (``.inner`` chains)."""
    while not hasattr(state, "world"):
        state = state.inner
    return state.world


# ---------------------------------------------------------------------------- run folders

def _grid_policy(cfg: Any, q, title: str) -> Policy:
    env = ShootingEnv()
    ep = cfg.env.replace(start_difficulty=float(cfg.train.eval_difficulty))
    state = lambda o: grid_state(o, cfg.grid)  # noqa: E731
    return Policy(env, ep, state, state, lambda o: o, cfg.agent.macro,
                  float(cfg.agent.discount), q,
                  float(cfg.train.eval_epsilon), cfg.env.world, lambda p: p.camera,
                  lambda p: jnp.int32(0), tuple(env.action_labels), NUM_GOAL_STATES, title)


def _cva_map(cfg: Any) -> CVAMap:
    return CVAMap(table2_env(cfg.task, cfg.ball_velocity), cfg.cva)


def _cva_policy(cfg: Any, smap: CVAMap, q, fitted, title: str) -> Policy:
    shoot_pass = getattr(smap.base, "unwrapped", smap.base)
    cols = int(np.ceil(np.sqrt(smap.num_states)))
    return Policy(smap.env, smap.env_params(fitted, cfg.env), lambda o: o["index"],
                  lambda o: o["perceived"], lambda o: o["state"], cfg.agent.macro,
                  float(cfg.agent.discount), q, 0.0, cfg.env.world,
                  lambda p: shoot_pass.learner_camera(p.inner.inner),
                  lambda p: shoot_pass.roles(p.inner.inner)[0],
                  tuple(shoot_pass.action_labels), cols, title)


def _cva_prepared(smap: CVAMap, traced: Any, key) -> Any:
    """The CVA map's fitted parameters (models, codebooks) as its run built them:
    ``Program.init``'s key, the learner's traced config ``traced`` (the engine's
    per-learner config arrays)."""
    return jax.jit(lambda k, c: smap.prepare(jax.random.fold_in(k, PREPARE_STREAM), c))(
        key, traced)


#: experiment name -> the state map its tabular learner learns on ("grid": the grid;
#: "cva": Table 2's)
RENDERABLE = {"grid_shooting": "grid", "table2_shoot_pass": "cva"}


def _final_carry(folder: Path, spec: dict, group, learner: int) -> Any:
    """Learner ``learner`` of ``group``'s carry at the end of its run (the run's last
    checkpoint of that group)."""
    where = folder / "checkpoints"
    step = group.step_offset + group.num_chunks
    if not where.is_dir():
        raise EngineError(f"{folder} keeps no checkpoints/ (the final Q tables): rerun it, or "
                          f"render --policy random")
    if not (where / str(step)).is_dir():  # orbax names a step's folder by the step
        raise EngineError(f"{folder}/checkpoints has no checkpoint of the end of the run "
                          f"(step {step}); rerun it, or render --policy random")
    ck = Checkpoints(where, spec["fingerprint"])
    try:
        n = group.num_learners
        shape = jax.eval_shape(jax.vmap(group.program.init),
                               jax.ShapeDtypeStruct((n, 2), np.uint32),
                               jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype),
                                            group.configs))
        like = jax.tree.map(lambda s: np.zeros(s.shape, s.dtype), shape)
        carry, _ = ck.restore(step, like)
    finally:
        ck.close()
    return jax.tree.map(lambda x: jnp.asarray(x[learner]), carry)


def _part_of(count: int, learners: int, learner: int) -> Shard:
    """The part of ``count`` that holds global learner ``learner`` of ``learners``."""
    return next(sh for sh in (Shard(i, count) for i in range(1, count + 1))
                if learner < sh.learner_range(learners)[1])


def _shard_learner(folder: Path, spec: dict, exp, plan, group, point: int, seed: int
                   ) -> tuple[Any, int]:
    """``(group, learner)`` of (``point``, ``seed``) in the checkpoints of the shard folder
    ``folder``: its part's group and the learner's index there; EngineError (one line)
    naming the part to render when this one does not hold it."""
    shard = Shard(int(spec["shard"]["index"]), int(spec["shard"]["count"]))
    splan = make_plan(exp, plan.config, plan.sweep, plan.seeds, plan.base_seed, shard)
    part = next(g for g in splan.groups if g.index == group.index)
    at = 0
    for p, lo, hi in part.members:
        if p == point and lo <= seed < hi:
            return part, at + seed - lo
        at += hi - lo
    lo, hi = shard.learner_range(plan.num_learners)
    other = _part_of(shard.count, plan.num_learners, point * plan.seeds + seed)
    raise EngineError(f"{folder} is part {shard} of a sharded run (learners {lo}-{hi - 1}, "
                      f"learner = point x {plan.seeds} + seed): point {point} seed {seed} "
                      f"is in part {other}; render that part's folder with the same "
                      f"--point and --seed")


def _merged_has_no_checkpoints(folder: Path, summary: dict, plan, point: int, seed: int
                               ) -> EngineError:
    """The error of a merged run's learned policy: its shards keep the checkpoints."""
    shards = [x for x in summary.get("shards") or [] if isinstance(x, dict)]
    part = _part_of(max(len(shards), 1), plan.num_learners, point * plan.seeds + seed)
    name = next((x.get("folder") for x in shards if x.get("shard") == str(part)), None)
    where = f" (its folder: {name})" if name else ""
    return EngineError(f"{folder} is a merged run (vbl merge), which keeps no checkpoints/ "
                       f"(the final Q tables); its shards keep theirs: render part {part}"
                       f"{where}, which holds point {point} seed {seed}, with the same "
                       f"--point and --seed, or render --policy random")


def load_policy(folder: str | Path, policy: str = "learned", point: int = 0,
                seed: int = 0) -> Policy:
    """The ``policy`` ("learned" or "random") of sweep point ``point``, seed ``seed`` of the
    finished run folder ``folder`` (a whole run, one of its shards, or their merge;
    ``point`` and ``seed`` are the whole run's); EngineError (one line) when it cannot be
    built."""
    if policy not in POLICIES:
        raise EngineError(f"--policy must be one of {list(POLICIES)}, got {policy!r}")
    folder = Path(folder)
    exp, res, spec = load_run(folder, shard_ok=True)
    kind = RENDERABLE.get(exp.name)
    if kind is None:
        raise EngineError(f"{folder} is a run of {exp.name}, whose policy vbl render cannot "
                          f"rebuild (renderable: {', '.join(sorted(RENDERABLE))})")
    plan = make_plan(exp, res.config, spec.get("sweep", {}), int(spec.get("seeds", 1)),
                     int(spec.get("base_seed", 0)))
    if not 0 <= point < len(plan.points):
        raise EngineError(f"--point must be in [0, {len(plan.points) - 1}] (the run's sweep "
                          f"points), got {point}")
    if not 0 <= seed < plan.seeds:
        raise EngineError(f"--seed must be in [0, {plan.seeds - 1}] (the run's seeds), "
                          f"got {seed}")
    group = next(g for g in plan.groups if point in g.point_ids)
    cfg = group.point_configs[group.point_ids.index(point)]
    values = ", ".join(f"{k}={v}" for k, v in plan.points[point].items())
    title = f"{exp.name}{' ' + values if values else ''}, seed {seed}, {policy} policy"
    j = group.point_ids.index(point) * plan.seeds + seed  # the learner in the group
    if policy == "learned":
        if "shards" in res.summary and not (folder / "checkpoints").is_dir():
            raise _merged_has_no_checkpoints(folder, res.summary, plan, point, seed)
        part, k = (group, j) if "shard" not in spec else _shard_learner(
            folder, spec, exp, plan, group, point, seed)
        carry = _final_carry(folder, spec, part, k)
    if kind == "grid":
        q = carry.learner.q if policy == "learned" else jnp.zeros(
            (NUM_GRID_STATES, cfg.agent.num_actions), F32)
        return _grid_policy(cfg, q, title)
    smap = _cva_map(cfg)
    if policy == "learned":
        return _cva_policy(cfg, smap, carry.learner.q, carry.fitted, title)
    traced = jax.tree.map(lambda x: jnp.asarray(x[j]), group.configs)
    fitted = _cva_prepared(smap, traced, jnp.asarray(plan.init_keys[seed]))
    return _cva_policy(cfg, smap, jnp.zeros((smap.num_states, cfg.agent.num_actions), F32),
                       fitted, title)


# ---------------------------------------------------------------------------- rollout

def trajectories(pol: Policy, key: jax.Array, episodes: int, max_steps: int) -> dict:
    """``episodes`` fresh starts (vmap), ``max_steps`` primitives each (``lax.scan``) under
    the learner's macro-action wrapper. Returns per episode and step (leading axes
    ``(episodes, max_steps)``): ``robots``, ``ball`` (the world before the step),
    ``index`` (discrete state), ``vector`` (state vector), ``action`` (primitive in force),
    ``alive`` (the step belongs to the first episode), ``done`` (the episode ended at this
    step), ``success`` (it scored at this step),
    ``camera`` and ``me`` (the learner's camera and robot)."""
    wrapper = MacroWrapper(pol.env, pol.state_fn, pol.macro, stop_key(pol.macro.stop_on),
                           pol.perceive_fn)
    wp = macro_env_params(pol.env_params, pol.macro, pol.discount)

    def one(k, wp, q):
        k0, k1 = jax.random.split(k)
        obs, st = wrapper.reset(k0, wp)

        def body(carry, kt):
            st, obs, alive = carry
            ka, ks = jax.random.split(kt)
            a = select_action(ka, q[st.index], pol.epsilon, "epsilon_greedy")
            obs2, st2, _, term, trunc, info = wrapper.step(ks, st, a, wp)
            world = _find_world(st.inner)
            rec = dict(robots=world.robots, ball=world.ball, index=st.index,
                       vector=jnp.asarray(pol.vector_fn(obs), F32).reshape(-1),
                       action=info["macro"]["action"], alive=alive,
                       done=alive & (term | trunc),
                       success=alive & jnp.asarray(info["success"], bool))
            return (st2, obs2, alive & ~(term | trunc)), rec

        _, recs = jax.lax.scan(body, (st, obs, jnp.ones((), bool)),
                               jax.random.split(k1, max_steps))
        return recs

    # the params are arguments (traced, as in the engine's programs), not constants
    out = jax.jit(jax.vmap(one, in_axes=(0, None, None)))(jax.random.split(key, episodes),
                                                          wp, pol.q)
    out["camera"] = pol.camera_fn(pol.env_params)
    out["me"] = pol.me_fn(pol.env_params)
    return out


# ---------------------------------------------------------------------------- frames

def _sizes(vp: VideoParams) -> tuple[int, int, int]:
    """(camera width, top width, panel width) at frame height ``vp.height``."""
    h = vp.height
    return (round(h * PAPER_WIDTH / PAPER_HEIGHT), round(h * TOP_WIDTH / TOP_HEIGHT),
            max(8, round(h * vp.panel_frac)))


def _panel(index, vector, scale, action, num_states: int, cols: int, num_actions: int,
           h: int, w: int) -> jax.Array:
    """(h, w, 3) info panel: the state grid (top half), the state vector's bars (each
    component divided by ``scale``, its largest magnitude in the video), the action boxes
    (bottom strip)."""
    rows = -(-num_states // cols)
    y = (jnp.arange(h, dtype=F32)[:, None] + 0.5) / h
    x = (jnp.arange(w, dtype=F32)[None, :] + 0.5) / w
    img = jnp.broadcast_to(jnp.asarray(PANEL_BG, F32), (h, w, 3))
    # state grid in the top half: cell (r, c) of state r * cols + c
    gy = y / 0.5
    r, c = jnp.floor(gy * rows), jnp.floor(x * cols)
    in_grid = (gy < 1.0) & (r * cols + c < num_states)
    here = in_grid & (r == index // cols) & (c == index % cols)
    img = jnp.where(in_grid[..., None], jnp.asarray(CELL_RGB, F32), img)
    # the current cell is drawn at least 3 px wide and tall so that it shows in any grid
    near = (jnp.abs(r - index // cols) * (h * 0.5 / rows) < 1.5) & (
        jnp.abs(c - index % cols) * (w / cols) < 1.5) & in_grid
    img = jnp.where((here | near)[..., None], jnp.asarray(STATE_RGB, F32), img)
    # bars between 0.55 and 0.85 of the height, zero line at 0.7
    d = vector.shape[0]
    v = jnp.clip(vector / jnp.maximum(scale, 1e-9), -1.0, 1.0)
    k = jnp.clip(jnp.floor(x * d).astype(jnp.int32), 0, d - 1)
    vk = v[k]
    top = 0.7 - 0.15 * jnp.maximum(vk, 0.0)
    bottom = 0.7 - 0.15 * jnp.minimum(vk, 0.0)
    bar = (y >= top) & (y <= bottom) & ((x * d - k) < 0.8)
    img = jnp.where((bar & (vk >= 0))[..., None], jnp.asarray(BAR_POS_RGB, F32), img)
    img = jnp.where((bar & (vk < 0))[..., None], jnp.asarray(BAR_NEG_RGB, F32), img)
    # action boxes between 0.9 and 1.0 of the height
    ka = jnp.floor(x * num_actions).astype(jnp.int32)
    box = (y >= 0.9) & ((x * num_actions - ka) < 0.85)
    on = jnp.where((ka == action)[..., None], jnp.asarray(ACTION_RGB, F32),
                   jnp.asarray(ACTION_OFF_RGB, F32))
    return jnp.where(box[..., None], on, img)


def render_frames(pol: Policy, traj: dict, vp: VideoParams) -> np.ndarray:
    """(frames, H, W, 3) uint8: the alive steps of every episode, in order (episode 0's
    first), each camera | top view | panel (without the caption)."""
    vp = validate(vp)
    cam_w, top_w, panel_w = _sizes(vp)
    rp = RenderParams(width=cam_w, height=vp.height, top_width=top_w, top_height=vp.height)
    alive = np.asarray(traj["alive"])
    sel = np.nonzero(alive.reshape(-1))[0]
    flat = {k: jnp.asarray(np.asarray(traj[k]).reshape((-1,) + np.shape(traj[k])[2:])[sel])
            for k in ("robots", "ball", "index", "vector", "action")}
    scale = jnp.max(jnp.abs(flat["vector"]), axis=0)
    num_states, num_actions = pol.q.shape
    cam, me = traj["camera"], traj["me"]

    def frame(x):
        img, top = render_world(x["robots"], x["ball"], pol.world, cam, rp, me=me)
        panel = _panel(x["index"], x["vector"], scale, x["action"], num_states,
                       pol.grid_cols, num_actions, vp.height, panel_w)
        return to_uint8(jnp.concatenate([img, top, panel], axis=1))

    return np.asarray(jax.jit(lambda xs: jax.lax.map(frame, xs, batch_size=vp.batch))(flat))


def _captions(pol: Policy, traj: dict, dt: float) -> list[str]:
    alive, action = np.asarray(traj["alive"]), np.asarray(traj["action"])
    index, success = np.asarray(traj["index"]), np.asarray(traj["success"])
    done = np.asarray(traj["done"])
    out = []
    for e in range(alive.shape[0]):
        n = int(alive[e].sum())
        for t in range(n):
            end = "  GOAL" if success[e, t] else "  (ends)" if done[e, t] else ""
            out.append(f"episode {e + 1}  {t * dt:4.1f} s  state {int(index[e, t])}  "
                       f"action {pol.labels[int(action[e, t])]}{end}")
    return out


def write_video(frames: np.ndarray, captions: list[str], out: Path, vp: VideoParams) -> None:
    """Write ``frames`` with a caption strip each to ``out`` (.gif or .mp4, imageio; an MP4's
    sizes are padded to even with black)."""
    import imageio.v2 as imageio
    from PIL import Image, ImageDraw

    kw = dict(fps=float(vp.fps)) if out.suffix.lower() == ".mp4" else dict(
        duration=1000.0 / float(vp.fps), loop=0)  # GIF (Pillow): ms per frame
    even = out.suffix.lower() == ".mp4"  # H.264 in yuv420p needs even sizes: pad with black
    if even:
        kw.update(macro_block_size=MP4_BLOCK)
    try:
        with warnings.catch_warnings(), imageio.get_writer(out, **kw) as w:
            # imageio-ffmpeg starts ffmpeg with fork + exec at once, which is safe
            warnings.filterwarnings("ignore", "os.fork", RuntimeWarning)
            for f, text in zip(frames, captions, strict=True):
                strip = Image.new("RGB", (f.shape[1], vp.caption), (0, 0, 0))
                ImageDraw.Draw(strip).text((2, 1), text, fill=CAPTION_RGB)
                img = np.concatenate([f, np.asarray(strip)], axis=0)
                if even:
                    img = np.pad(img, ((0, -img.shape[0] % MP4_BLOCK),
                                       (0, -img.shape[1] % MP4_BLOCK), (0, 0)))
                w.append_data(img)
    except OSError as e:  # a full disk while writing: no half-written video is left
        out.unlink(missing_ok=True)
        raise EngineError(f"cannot write {out}: {e.strerror or e}; free some space or pick "
                          f"another --out") from None


FRAME_COPIES = 2  #: copies of the frames held at once (the rendered array, the host's)


def _check_out(out: Path) -> None:
    """EngineError (one line) unless a file can be created in ``out``'s folder (tested
    with a probe file, before anything is rendered)."""
    import os

    if not out.parent.is_dir():
        raise EngineError(f"cannot write {out}: no folder {out.parent}")
    if out.is_dir():
        raise EngineError(f"cannot write {out}: it is a folder; --out names a .gif or .mp4 "
                          f"file")
    probe = out.parent / f".vbl-probe-{os.getpid()}"
    try:
        os.close(os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
        os.unlink(probe)
    except OSError as e:
        raise EngineError(f"cannot write {out}: {e.strerror or e} in {out.parent}; make the "
                          f"folder writable or pick another --out") from None


def _check_render_memory(episodes: int, vp: VideoParams) -> int:
    """Refuse (one line, before anything is loaded or compiled) a video whose frames may
    not fit in memory: ``episodes`` x ``max_steps`` frames at most (every episode that
    runs to the end), each ``height`` x width x 3 bytes, :data:`FRAME_COPIES` copies."""
    from vbl.engine.memory import available_memory, check_bytes

    cam_w, top_w, panel_w = _sizes(vp)
    frame = vp.height * (cam_w + top_w + panel_w) * 3
    per_episode = FRAME_COPIES * vp.max_steps * frame
    fit = available_memory() // per_episode
    return check_bytes(
        episodes * per_episode,
        f"--episodes {episodes} of up to {vp.max_steps} frames each (--max-steps) at "
        f"{vp.height} x {cam_w + top_w + panel_w} px may need up to",
        f"use at most --episodes {fit} at these settings, or a smaller --max-steps or "
        f"--height" if fit >= 1 else "use a smaller --max-steps or --height")


class Video(NamedTuple):
    """What :func:`render_run` wrote: ``frames`` (count), ``height`` x ``width`` px, the
    rollout (:func:`trajectories`) the frames show and what they show (``title``)."""

    frames: int
    height: int
    width: int
    traj: dict
    title: str  #: experiment, sweep point, seed, policy


def render_run(folder: str | Path, out: str | Path, episodes: int, policy: str = "learned",
               point: int = 0, seed: int = 0, key: int = 0,
               vp: VideoParams | None = None) -> Video:
    """``vbl render``: write ``episodes`` episodes of a run folder's policy to ``out``, in the
    engine's precision (the run's own numerics). EngineError (one line) for bad input."""
    vp = validate(VideoParams() if vp is None else vp)
    out = Path(out)
    if out.suffix.lower() not in EXTENSIONS:
        raise EngineError(f"--out must end in {' or '.join(EXTENSIONS)}, got {out.name!r}")
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise EngineError(f"--episodes must be an int >= 1, got {episodes!r}")
    _check_out(out)
    _check_render_memory(episodes, vp)
    with engine_precision():
        pol = load_policy(folder, policy, point, seed)
        traj = trajectories(pol, jax.random.PRNGKey(key), episodes, vp.max_steps)
        frames = render_frames(pol, traj, vp)
    write_video(frames, _captions(pol, traj, float(pol.world.action_dt)), out, vp)
    h, w = frames.shape[1] + vp.caption, frames.shape[2]
    if out.suffix.lower() == ".mp4":
        h, w = h + -h % MP4_BLOCK, w + -w % MP4_BLOCK
    return Video(frames.shape[0], h, w, traj, pol.title)
