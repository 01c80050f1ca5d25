"""vbl render: episode videos of a run folder's policy (vbl/programs/video.py).

The run folders are made here without training: ``config.json`` from the engine's own
``resolve`` (what ``vbl run`` writes) and, for the learned policy, a final checkpoint whose
Q table has one best action. Independent truths: the file's frame count equals the
rollout's alive steps and its size the documented layout; a table whose best action is
``F`` everywhere acts ``F`` in every frame; the red pixels of the camera part of a frame
sit where the analytic Section 2 camera puts the ball.
"""

from __future__ import annotations

import json
import subprocess
import sys

import imageio.v2 as imageio
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tests.engine_helpers import REPO, one_error_line, zero_carry
from vbl.engine.checkpoint import Checkpoints
from vbl.engine.registry import discover, get
from vbl.engine.runner import resolve
from vbl.engine.sweep import make_plan
from vbl.programs.video import (
    RENDERABLE,
    VideoParams,
    _sizes,
    load_policy,
    render_frames,
    render_run,
)
from vbl.vision.blobs import BlobParams, section2_from_pixels
from vbl.vision.section2 import SEC2_BALL_POS, SEC2_BALL_SIZE, SEC2_BALL_VISIBLE
from vbl.world.robots import TWO_MOTOR_LABELS

VP = VideoParams(height=48, max_steps=40, caption=10)
FORWARD = TWO_MOTOR_LABELS.index("F")


def _fake_run(folder, name, sets=None, seeds=1):
    """A finished-looking run folder of experiment ``name`` (config.json as vbl run writes
    it, a summary.json without results); returns (experiment, config, spec)."""
    discover()
    exp = get(name)
    folder.mkdir(parents=True)
    config, _, _, spec = resolve(exp, sets or {}, None, seeds, 0, True, None)
    (folder / "config.json").write_text(json.dumps(spec))
    (folder / "summary.json").write_text(json.dumps({"experiment": name, "points": []}))
    return exp, config, spec


@pytest.fixture(scope="module")
def grid_run(tmp_path_factory):
    """A grid_shooting folder (greedy evaluation) whose final Q tables prefer "F"."""
    folder = tmp_path_factory.mktemp("video") / "grid"
    exp, config, spec = _fake_run(folder, "grid_shooting", {"train.eval_epsilon": 0.0})
    plan = make_plan(exp, config, spec["sweep"], spec["seeds"], 0)
    g = plan.groups[0]
    carry = zero_carry(g)
    q = np.zeros(carry.learner.q.shape, np.float32)
    q[..., FORWARD] = 1.0
    carry = carry.replace(learner=carry.learner.replace(q=q))
    ck = Checkpoints(folder / "checkpoints", spec["fingerprint"])
    ck.save(g.step_offset + g.num_chunks, carry, {"group": 0})
    ck.close()
    return folder


def test_learned_gif_frames_size_and_actions(grid_run, tmp_path):
    out = tmp_path / "v.gif"
    v = render_run(grid_run, out, 2, "learned", point=1, vp=VP)
    alive = np.asarray(v.traj["alive"])
    assert v.frames == alive.sum() >= 2
    assert np.all(np.asarray(v.traj["action"])[alive] == FORWARD)  # the table's best action
    frames = np.stack(imageio.mimread(out))
    cam_w, top_w, panel_w = _sizes(VP)
    assert frames.shape[:3] == (v.frames, VP.height + VP.caption, cam_w + top_w + panel_w)
    assert (v.height, v.width) == frames.shape[1:3]
    assert np.abs(np.diff(frames[..., :3].astype(int), axis=0)).max(axis=(1, 2, 3)).min() > 0
    from PIL import Image

    with Image.open(out) as im:  # real time: 1 / fps s per frame
        im.seek(1)
        assert im.info["duration"] == pytest.approx(1000 / VP.fps)


@pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")  # the reader starts ffmpeg
def test_mp4(grid_run, tmp_path):
    out = tmp_path / "v.mp4"
    v = render_run(grid_run, out, 1, "learned", point=1, vp=VP)
    r = imageio.get_reader(out)
    assert r.count_frames() == v.frames
    assert tuple(r.get_meta_data()["size"]) == (v.width, v.height)
    assert v.width % 2 == 0 and v.height % 2 == 0


def test_random_policy_needs_no_checkpoint(tmp_path):
    bare = tmp_path / "bare"
    _fake_run(bare, "grid_shooting")
    out = tmp_path / "r.gif"
    vp = VideoParams(height=120, max_steps=40)
    v = render_run(bare, out, 3, "random", key=3, vp=vp)
    assert len(imageio.mimread(out)) == v.frames >= 3
    pol = load_policy(bare, "random")
    assert not np.any(pol.q)  # the all-zero table: uniformly random tie-breaking
    alive = np.asarray(v.traj["alive"])
    assert len(set(np.asarray(v.traj["action"])[alive].tolist())) > 1
    # the red pixels sit where the analytic Section 2 camera puts the ball (the frames are
    # re-rendered: the GIF's palette may shift colours)
    frames = render_frames(pol, v.traj, vp)
    obs = np.asarray(v.traj["vector"])[alive]  # the analytic Section 2 features
    cam = pol.env_params.camera
    cam_w = _sizes(vp)[0]
    px = cam.image_width / cam_w  # one pixel of the frame in analytic px
    feats = np.asarray(jax.jit(jax.vmap(lambda im: section2_from_pixels(im, cam, BlobParams())))(
        jnp.asarray(frames[:, :, :cam_w])))
    half = cam.image_width / 2
    clear = ((obs[:, SEC2_BALL_VISIBLE] > 0.5) & (obs[:, SEC2_BALL_SIZE] >= 4 * px)
             & (np.abs(obs[:, SEC2_BALL_POS]) + obs[:, SEC2_BALL_SIZE] / 2 < half - 2 * px))
    assert clear.sum() >= 5
    assert np.all(feats[clear, SEC2_BALL_VISIBLE] > 0.5)
    # the centre of the red extent: within a pixel (docs/render.md's bound: half a pixel
    # at each end of the extent)
    err = np.abs(feats[clear, SEC2_BALL_POS] - obs[clear, SEC2_BALL_POS])
    assert err.max() <= px, err.max() / px


@pytest.mark.parametrize("case", ["no_folder", "extension", "episodes", "not_renderable",
                                  "point"])
def test_bad_input_is_one_line_exit_2(case, grid_run, tmp_path, capsys):
    from vbl.cli import main

    folder, extra = str(grid_run), []
    out = str(tmp_path / "x.gif")
    if case == "no_folder":
        folder = str(tmp_path / "missing")
    elif case == "extension":
        out = str(tmp_path / "x.avi")
    elif case == "episodes":
        extra = ["--episodes", "0"]
    elif case == "point":
        extra = ["--point", "2"]
    else:
        folder = str(tmp_path / "toy")
        _fake_run(tmp_path / "toy", "toy_bandit")
    capsys.readouterr()
    code = main(["render", folder, "--out", out, *extra])
    line = one_error_line(capsys.readouterr().err)
    assert code == 2, line
    want = {"no_folder": "not a run folder", "extension": ".gif or .mp4",
            "episodes": "--episodes", "point": "--point must be in [0, 1]",
            "not_renderable": "cannot rebuild"}[case]
    assert want in line, line


def test_the_committed_grid_run_renders_its_learned_policy(tmp_path):
    """docs/results/reproduce/grid_shooting keeps its final checkpoint (the README's GIF)."""
    folder = REPO / "docs" / "results" / "reproduce" / "grid_shooting"
    v = render_run(folder, tmp_path / "g.gif", 1, "learned", point=1, vp=VP)
    frames = imageio.mimread(tmp_path / "g.gif")
    assert len(frames) == v.frames >= 2
    assert any(not np.array_equal(a, b) for a, b in zip(frames, frames[1:], strict=False))


def test_committed_run_without_checkpoints_says_so(tmp_path):
    """Committed run folders keep results and, but for grid_shooting's, no checkpoints:
    the learned policy of such a folder is one line, exit 2."""
    folder = REPO / "docs" / "results" / "reproduce" / "table2_shoot_pass"
    r = subprocess.run([sys.executable, "-m", "vbl.cli", "render", str(folder), "--out",
                        str(tmp_path / "x.gif")], cwd=REPO, capture_output=True, text=True,
                       timeout=300)
    line = one_error_line(r.stderr)
    assert r.returncode == 2 and "--policy random" in line, line


@pytest.mark.slow
def test_table2_random_policy_films_the_learner(tmp_path):
    """Table 2 (pass task, CVA state): the CVA models and codebooks are rebuilt from the
    run's config; the learner is the passer (robot 1), its state indices are codebook
    cells and its state vector is the one the quantiser sees."""
    folder = tmp_path / "t2"
    _, config, _ = _fake_run(folder, "table2_shoot_pass", {"cva.collect_steps": 1500})
    vp = VideoParams(height=48, max_steps=30)
    v = render_run(folder, tmp_path / "t.gif", 1, "random", point=3, vp=vp)
    assert len(imageio.mimread(tmp_path / "t.gif")) == v.frames >= 1
    assert int(v.traj["me"]) == 1
    alive = np.asarray(v.traj["alive"])
    idx = np.asarray(v.traj["index"])[alive]
    assert np.all((idx >= 0) & (idx < np.prod(config.cva.quantizer.group_codes)))
    from vbl.agents.cva_state import state_dim
    from vbl.envs.shoot_pass import ShootPassEnv

    d = state_dim(ShootPassEnv(config.task), config.cva)  # what the quantiser sees
    assert np.asarray(v.traj["vector"]).shape[-1] == d


def render_points_block() -> str:
    """docs/render.md's list of the renderable experiments' sweep points, from their
    default sweeps (the order of a run's points)."""
    discover()
    lines = []
    for name in sorted(RENDERABLE):
        exp = get(name)
        config, sweep, seeds, _ = resolve(exp)
        plan = make_plan(exp, config, sweep, seeds, 0)
        pts = [", ".join(f"{k.rsplit('.', 1)[-1]}={v}" for k, v in p.items())
               for p in plan.points]
        lines.append(f"* `{name}`: " + "; ".join(f"{i} `{p}`" for i, p in enumerate(pts)))
    return "\n".join(lines)


def test_render_doc_lists_the_points_of_the_default_sweeps():
    """The --point indices docs/render.md gives are those of the experiments' sweeps
    (regenerate: PYTHONPATH=. python tests/test_video.py)."""
    text = (REPO / "docs" / "render.md").read_text()
    begin, end = "<!-- render points -->\n", "\n<!-- /render points -->"
    block = text[text.index(begin) + len(begin):text.index(end)]
    assert block == render_points_block(), (
        "docs/render.md: regenerate: PYTHONPATH=. python tests/test_video.py")


if __name__ == "__main__":
    path = REPO / "docs" / "render.md"
    text = path.read_text()
    head, rest = text.split("<!-- render points -->\n", 1)
    path.write_text(head + "<!-- render points -->\n" + render_points_block()
                    + rest[rest.index("\n<!-- /render points -->"):])
