"""The library parts Figure 9 builds from: the ball-size schedule, the steering policy,
a program run inside another, the per-trial records and the change report.

Truth: hand-computed values (radii at given trials, the primitive for a given image
position, sums of a counting program, the windows of a hand-made success record).
"""

import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vbl.agents.segmentation_learner import per_trial
from vbl.agents.steering import steer_action
from vbl.engine import Program
from vbl.engine.nested import run_program
from vbl.envs.schedules import BallChangeParams, ball_radius_at, ball_radius_params
from vbl.envs.shooting import ShootingParams
from vbl.params import ParamError, validate
from vbl.programs.segmentation_figures import (
    change_report,
    change_rows,
    change_window,
    plot_fig8,
    plot_fig9,
)
from vbl.vision.section2 import (
    SEC2_BALL_LOST_SIDE,
    SEC2_BALL_POS,
    SEC2_BALL_VISIBLE,
    SEC2_DIM,
)
from vbl.world.robots import action_labels


def test_ball_radius_changes_at_the_given_trials_traced():
    p = BallChangeParams(radius_0=0.3, radius_1=0.2, radius_2=0.1, change_trial_1=5,
                         change_trial_2=9)
    trials = jnp.array([0, 4, 5, 8, 9, 100])
    got = jax.jit(ball_radius_at)(trials, p)
    np.testing.assert_allclose(np.asarray(got), [0.3, 0.3, 0.2, 0.2, 0.1, 0.1], rtol=1e-6)
    assert got.dtype == jnp.float32
    env = jax.jit(ball_radius_params)(ShootingParams(), jnp.int32(6), p)
    assert float(env.world.ball.radius) == pytest.approx(0.2)
    assert float(env.world.goal.width) == ShootingParams().world.goal.width


def test_ball_schedule_rejects_a_second_change_before_the_first():
    with pytest.raises(ParamError, match="change_trial_2"):
        validate(BallChangeParams(change_trial_1=10, change_trial_2=5))


@pytest.mark.parametrize("visible,x2,lost,want", [
    (1.0, 50.0, 0.0, "FR"), (1.0, -50.0, 0.0, "FL"), (1.0, 10.0, 0.0, "F"),
    (1.0, -19.0, 1.0, "F"), (0.0, 0.0, 1.0, "TR"), (0.0, 0.0, -1.0, "TL")])
def test_steering_policy_by_hand(visible, x2, lost, want):
    labels = action_labels("two_motor")
    obs = jnp.zeros(SEC2_DIM).at[SEC2_BALL_VISIBLE].set(visible).at[SEC2_BALL_POS].set(x2)
    obs = obs.at[SEC2_BALL_LOST_SIDE].set(lost)
    assert labels[int(steer_action(obs, 20.0, labels))] == want


def test_run_program_sums_chunk_totals_and_returns_final():
    """init 1, each chunk doubles the carry and reports it: after 4 chunks the carry is 16,
    the reported values sum to 2 + 4 + 8 + 16 = 30; final sees the carry and its key."""
    prog = Program(init=lambda k, c: jnp.float32(1.0) * c,
                   step=lambda x, c: (2 * x, {"x": 2 * x, "other": x}), num_chunks=4,
                   final=lambda x, c, k: {"last": x, "key": k})
    fin, tot = jax.jit(lambda: run_program(prog, 1.0, jax.random.PRNGKey(0),
                                           jax.random.PRNGKey(9), lambda m: {"s": m["x"]}))()
    assert float(fin["last"]) == 16.0 and float(tot["s"]) == 30.0 and set(tot) == {"s"}
    np.testing.assert_array_equal(np.asarray(fin["key"]), np.asarray(jax.random.PRNGKey(9)))


def test_per_trial_records_each_finished_trial_once():
    """Steps of trials 0 (fails at step 1), 1 (scores at step 3), 2 (past the record of 2
    trials: dropped); unfinished steps write nothing."""
    out = dict(done=jnp.array([False, True, False, True, True]),
               success=jnp.array([False, False, False, True, True]),
               trial=jnp.array([0, 0, 1, 1, 2]), states=jnp.array([1, 2, 3, 4, 5]))
    s, n = per_trial(out, jnp.full(2, -1.0, jnp.float32), jnp.full(2, -1.0, jnp.float32))
    np.testing.assert_array_equal(np.asarray(s), [0.0, 1.0])
    np.testing.assert_array_equal(np.asarray(n), [2.0, 4.0])


def test_change_window_and_report_by_hand(tmp_path):
    """Changes at 10 and 20 of 40 trials: windows of min(50, 10 // 2) = 5. Trials 5-9
    succeed for both seeds (1.0 before), none right after (0.0), seed 0 all of 15-19 (0.5
    at the end of recovery). Change 2: 0.5 before, 0.0 after and at the end. Verdicts are
    paired over the seeds (Student t, 12.706 for 1 degree of freedom)."""
    assert change_window((10, 20), 40) == 5 and change_window((400, 750), 1110) == 50
    succ = np.zeros((2, 40))
    succ[:, 5:10] = 1.0
    succ[0, 15:20] = 1.0
    states = np.tile(np.arange(40.0), (2, 1))
    md = change_report(succ, states, (10, 20), 5)
    # 0.5 +- 12.706 * 0.707 / sqrt(2) = 6.353 crosses [0, 1]: with 2 seeds, no interval
    assert md[2] == ("| 1 (trial 10) | 1.000 ± 0.000 (5-10) | 0.000 ± 0.000 (10-15) | "
                     "0.500 (2 seeds: too few for an interval) (15-20) | 9.0 -> 15.0 -> 19.0 |")
    verdicts = {r.split("|")[1].strip(): [c.strip() for c in r.split("|")[2:5]]
                for r in md if re.match(r"\| [12] \| ", r)}
    # change 1: before - after = (1, 1): drops; end - after = (1, 0): +0.5 +- 6.353, open;
    # states end - before = 10 for both seeds
    assert verdicts["1"][0] == "yes (+1 ± 0)" and verdicts["1"][2] == "yes (+10 ± 0)"
    assert verdicts["1"][1].startswith("not resolved at 2 seeds (+0.5 ± 6.35")
    # change 2: before - after = (1, 0): open; no recovery at all (0 - 0)
    assert verdicts["2"][0].startswith("not resolved at 2 seeds (+0.5 ± 6.35")
    assert verdicts["2"][1] == "not resolved at 2 seeds (+0 ± 0)"
    rows = change_rows(succ, states, (10, 20), 5)
    assert len(rows) == 2 and rows[0].ours == (
        "1.000 ± 0.000 / 0.000 ± 0.000 / 0.500 (2 seeds: too few for an interval)")
    fin = dict(trial_success=succ, trial_states=states,
               box_lo=np.zeros((2, 3, 5)), box_hi=np.ones((2, 3, 5)),
               box_active=np.array([[1.0, 0.0, 0.0]] * 2), box_action=np.zeros((2, 3)))
    assert plot_fig9(fin, (10, 20), tmp_path).is_file()
    assert plot_fig8(fin, (270.0, 480.0), action_labels("two_motor"), tmp_path).is_file()
