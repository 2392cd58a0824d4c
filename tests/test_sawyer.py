"""Sawyer peg push and pick & place: model, contract, solvability, walls, stability.

Physics compiles are the cost here (an MJX step takes 15-30 s to compile on this CPU), so
each task compiles ONE jitted rollout: H steps (lax.scan) of a batch of envs (vmap), each
env running the controller its mode picks (the scripted task controller, a push into the
central wall, a constant action, uniform random actions, random actions drifting toward
the peg). A module-scoped fixture runs it once per task; the tests read its record.
"""

import chex
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import envs
from envs import sawyer_peg
from envs.sawyer_peg import HAND_HIGH, HAND_LOW, HAND_START, SawyerPeg

TASKS = ("push", "pick_place")
H = 200
SCRIPT, WALL, CONST, RANDOM, SEEK, PIN = 0, 1, 2, 3, 4, 5
N_RANDOM = 50  # uniform random: 50 envs x 200 steps = 10,000 steps
N_SEEK = 25  # random drifting toward the peg: 25 envs x 200 steps
WALL_HEIGHTS = (0.01, 0.02, 0.035)  # hand heights of the pushes into the central wall
CONST_ACTION = (-1.0, -1.0, 1.0, -1.0)  # free motion: full speed in x, y and z, open
CONST_STEPS = 20


# --- controllers: pure functions (obs (7,), goal (3,), phase ()) -> (action (4,), phase) ---
def _move(hand, target, gain=0.6):
    """Action that steers the hand point to `target` (saturating P control)."""
    return jnp.clip(gain * (target - hand) / sawyer_peg.MOVE_SCALE, -1.0, 1.0)


def pick_place_controller(obs, goal, phase):
    """0: over the peg, descend, close; 1: lift to 0.2, carry over the wall; 2: release."""
    hand, opening, peg = obs[:3], obs[3], obs[4:]
    aligned = jnp.linalg.norm(hand[:2] - peg[:2]) < 0.004
    at_peg = aligned & (hand[2] < peg[2] + 0.004)
    approach = jnp.where(aligned, peg, jnp.concatenate([peg[:2], hand[2:]]))
    lift = jnp.concatenate([hand[:2], jnp.array([0.2])])
    carry = goal + (hand - peg)  # puts the peg (not the hand) on the goal
    target = jnp.select(
        [phase == 0, (phase == 1) & (hand[2] < 0.18), phase == 1], [approach, lift, carry], hand
    )
    grip = jnp.select([phase == 0, phase == 1], [jnp.where(at_peg, 1.0, -1.0), 1.0], -1.0)
    grasped = at_peg & (opening < 0.042)
    phase = jnp.where((phase == 0) & grasped, 1, phase)
    phase = jnp.where((phase == 1) & (jnp.linalg.norm(peg - goal) < 0.01), 2, phase)
    return jnp.append(_move(hand, target), grip), phase


def push_controller(obs, goal, phase):
    """0: behind the peg, above it; 1: descend closed; 2: push the peg onto the goal; 3: stop.

    Pushes along the line through the peg and the goal, the closed pads touching the peg
    (their half width plus the peg's = 0.03 behind its centre), slowly (gain 0.25), which
    keeps the peg from yawing off the pads.
    """
    hand, peg = obs[:3], obs[4:]
    to_goal = goal[:2] - peg[:2]
    dist = jnp.linalg.norm(to_goal)
    direction = to_goal / jnp.maximum(dist, 1e-6)
    behind = jnp.append(peg[:2] - 0.07 * direction, 0.1)
    low = jnp.append(peg[:2] - 0.07 * direction, 0.015)
    push = jnp.append(peg[:2] + (jnp.minimum(dist, 0.03) - 0.03) * direction, 0.015)
    target = jnp.select([phase == 0, phase == 1, phase == 2], [behind, low, push], hand)
    phase = jnp.where((phase == 0) & (jnp.linalg.norm(hand - behind) < 0.005), 1, phase)
    phase = jnp.where((phase == 1) & (hand[2] < 0.02), 2, phase)
    phase = jnp.where((phase == 2) & (dist < 0.02), 3, phase)
    return jnp.append(_move(hand, target, gain=0.25), 1.0), phase


def wall_push(obs, height, phase):
    """Closed gripper to the +x side of the peg at `height`, then full speed toward -x."""
    hand, peg = obs[:3], obs[4:]
    start = jnp.stack([jnp.minimum(peg[0] + 0.09, HAND_HIGH[0]), peg[1], 0.1])
    low = jnp.stack([hand[0], hand[1], height])
    action = jnp.select(
        [phase == 0, phase == 1],
        [_move(hand, start), _move(hand, low)],
        jnp.append(-1.0, _move(hand[1:], low[1:])),
    )
    phase = jnp.where((phase == 0) & (jnp.linalg.norm(hand - start) < 0.005), 1, phase)
    phase = jnp.where((phase == 1) & (jnp.abs(hand[2] - height) < 0.003), 2, phase)
    return jnp.append(action, 1.0), phase


def rim_pin(obs, phase):
    """Shoves the peg onto the back retaining wall with a half-open pad, presses it there and
    climbs: how a learned policy lifted the peg while that wall was a half-space plane."""
    hand, peg = obs[:3], obs[4:]
    above = jnp.stack([peg[0], peg[1] - 0.07, 0.2])
    low = jnp.stack([peg[0], peg[1] - 0.07, 0.03])
    action = jnp.select(
        [phase == 0, phase == 1, phase == 2],
        [_move(hand, above), _move(hand, low), jnp.array([0.0, 1.0, 0.0])],
        jnp.array([0.0, 1.0, 1.0]),  # keep pressing toward the wall while climbing
    )
    phase = jnp.where((phase == 0) & (jnp.linalg.norm(hand - above) < 0.005), 1, phase)
    phase = jnp.where((phase == 1) & (hand[2] < 0.035), 2, phase)
    phase = jnp.where((phase == 2) & (hand[1] > HAND_HIGH[1] - 0.006), 3, phase)
    return jnp.append(action, -0.5), phase


# --- the one compiled rollout per task ---------------------------------------------------
def make_rollout(env: SawyerPeg):
    """jit(vmap over envs, scan over H steps) of env.reset_with_goal / env.step."""
    controller = push_controller if env.task == "push" else pick_place_controller
    peg_dof = int(env.mj_model.jnt_dofadr[env.mj_model.joint("peg").id])
    step = chex.assert_max_traces(env.step, n=1)
    reset = chex.assert_max_traces(env.reset_with_goal, n=1)

    def policy(obs, goal, phase, key, mode, param):
        a_script, p_script = controller(obs, goal, phase)
        a_wall, p_wall = wall_push(obs, param[0], phase)
        a_pin, p_pin = rim_pin(obs, phase)
        a_random = jax.random.uniform(key, (4,), minval=-1.0, maxval=1.0)
        # Random actions drifting toward the peg: contact-rich (pinches, pushes, lifts).
        a_seek = jnp.clip(a_random + jnp.append(_move(obs[:3], obs[4:], 0.5), 0.0), -1, 1)
        action = jnp.select(
            [mode == SCRIPT, mode == WALL, mode == CONST, mode == SEEK, mode == PIN],
            [a_script, a_wall, param, a_seek, a_pin],
            a_random,
        )
        phase = jnp.select(
            [mode == SCRIPT, mode == WALL, mode == PIN], [p_script, p_wall, p_pin], phase
        )
        return action, phase

    def body(carry, key):
        state, phase, mode, param = carry
        keys = jax.random.split(key, mode.shape[0])
        action, phase = jax.vmap(policy)(state.obs, state.goal, phase, keys, mode, param)
        state = jax.vmap(step)(state, action)
        record = (state.obs, state.success, state.data.qvel[:, peg_dof : peg_dof + 6])
        return (state, phase, mode, param), record

    @jax.jit
    def rollout(key, goals, mode, param):
        """goals (B, 3), mode (B,), param (B, 4) -> (final EnvState, records (H, B, ...))."""
        k_reset, k_steps = jax.random.split(key)
        state = jax.vmap(reset)(jax.random.split(k_reset, mode.shape[0]), goals)
        carry = (state, jnp.zeros_like(mode), mode, param)
        (state, *_), records = jax.lax.scan(body, carry, jax.random.split(k_steps, H))
        return state, records

    return rollout


def _batch(env: SawyerPeg):
    """Per env: (goal, mode, param); the scripted envs come first, one per reachable goal."""
    # The scripted push goes straight from the start to (0.4, 0.4); the other two push
    # goals need a path around the wall, which a learner finds, not this controller.
    script_goals = env.goal_points[2:] if env.task == "push" else env.goal_points
    rows = [(g, SCRIPT, np.zeros(4)) for g in script_goals]
    rows += [(env.goal_points[0], WALL, np.array([h, 0, 0, 0])) for h in WALL_HEIGHTS]
    rows += [(env.goal_points[0], CONST, np.array(CONST_ACTION))]
    rows += [(env.goal_points[0], PIN, np.zeros(4))]
    for mode, n in ((RANDOM, N_RANDOM), (SEEK, N_SEEK)):
        rows += [(env.goal_points[i % 3], mode, np.zeros(4)) for i in range(n)]
    goals, modes, params = zip(*rows, strict=True)
    return (
        jnp.asarray(np.stack(goals), jnp.float32),
        jnp.asarray(modes, jnp.int32),
        jnp.asarray(np.stack(params), jnp.float32),
    )


def _run(task: str) -> dict:
    """Builds the env, compiles its rollout and runs it once (key 0); numpy records."""
    chex.clear_trace_counter()  # counters are keyed by function name, shared by both tasks
    env = envs.make(f"sawyer_{task}")
    rollout = make_rollout(env)
    inputs = _batch(env)
    final, (obs, success, peg_vel) = rollout(jax.random.key(0), *inputs)
    return {
        "env": env,
        "rollout": rollout,
        "inputs": inputs,
        "final": final,
        "obs": np.asarray(obs),  # (H, B, 7)
        "success": np.asarray(success),  # (H, B)
        "peg_vel": np.asarray(peg_vel),  # (H, B, 6)
        "goals": np.asarray(inputs[0]),
        "modes": np.asarray(inputs[1]),
    }


@pytest.fixture(scope="module")
def push_run():
    return _run("push")


@pytest.fixture(scope="module")
def pick_place_run():
    return _run("pick_place")


# The compiled scripted rollout costs about a minute per task on a cold 2-core CI: the
# default suite checks the physics on pick_place, both tasks under `slow`.
@pytest.fixture(scope="module", params=[pytest.param("push", marks=pytest.mark.slow), "pick_place"])
def run(request):
    return request.getfixturevalue(f"{request.param}_run")


@pytest.fixture(scope="module", params=TASKS)
def env(request):
    """An env without any physics compiled (for the cheap tests)."""
    return envs.make(f"sawyer_{request.param}")


def _first_success(record, i):
    """Index of the first step at which env i succeeded, else None."""
    hits = np.nonzero(record["success"][:, i])[0]
    return int(hits[0]) if hits.size else None


# --- model, attributes and pure maps (no physics compiled) ---------------------------------
def test_registry_and_attributes(env):
    assert env.name in envs.ENV_NAMES
    assert (env.obs_dim, env.action_dim, env.goal_dim) == (7, 4, 3)
    assert (env.horizon, env.success_radius) == (200, 0.05)
    z = 0.02 if env.task == "push" else 0.2
    np.testing.assert_allclose(
        env.goal_points, [[-0.3, 0.4, z], [-0.3, 0.8, z], [0.4, 0.4, z]], atol=1e-7
    )
    np.testing.assert_allclose(env.goal_low, [-0.6, 0.2, 0.0])
    np.testing.assert_allclose(env.goal_high, [0.6, 1.0, 0.3])
    mask = [1, 1, 0] if env.task == "push" else [1, 1, 1]
    np.testing.assert_array_equal(env.goal_noise_mask, mask)
    assert isinstance(env.mj_model, mujoco.MjModel)
    with pytest.raises(ValueError, match="unknown task"):
        SawyerPeg(task="slide")


def test_model_matches_spec(env):
    m = env.mj_model
    assert m.opt.timestep == 0.0025 and sawyer_peg.N_SUBSTEPS == 5
    assert m.opt.solver == mujoco.mjtSolver.mjSOL_NEWTON and m.opt.iterations == 8
    np.testing.assert_allclose(m.geom("peg").size, [0.06, 0.02, 0.02])
    wall_y = 0.25 if env.task == "push" else 0.4  # pick & place: the whole table depth
    np.testing.assert_allclose(m.geom("central_wall").size, [0.01, wall_y, 0.05])
    np.testing.assert_allclose(m.geom("central_wall").pos, [0.0, 0.6, 0.05])
    # Retaining walls: 0.06-high boxes whose inner faces are the table's edges (a half-space
    # plane would be a wall of unbounded height; test_peg_pinned_on_back_wall_...).
    for name, axis, edge in (
        ("rim_x_neg", 0, -0.7), ("rim_x_pos", 0, 0.7), ("rim_y_neg", 1, 0.2), ("rim_y_pos", 1, 1.0),
    ):  # fmt: skip
        geom = m.geom(name)
        assert geom.type == mujoco.mjtGeom.mjGEOM_BOX
        np.testing.assert_allclose(geom.quat, [1, 0, 0, 0])
        table_centre = (0.0, 0.6)[axis]
        inner = geom.pos[axis] - np.sign(geom.pos[axis] - table_centre) * geom.size[axis]
        np.testing.assert_allclose(inner, edge, atol=1e-9)
        np.testing.assert_allclose(geom.pos[2] + geom.size[2], 0.06, atol=1e-9)
        np.testing.assert_allclose(geom.pos[2] - geom.size[2], 0.0, atol=1e-9)
    # Contacts only through the explicit pairs, all of them with the peg.
    assert not (m.geom_contype | m.geom_conaffinity).any()
    names = [m.geom(int(g)).name for g in np.ravel([m.pair_geom1, m.pair_geom2], "F")]
    pairs = {frozenset(p) for p in zip(names[::2], names[1::2], strict=True)}
    others = {"table", "central_wall", "rim_x_neg", "rim_x_pos", "rim_y_neg", "rim_y_pos"}
    assert pairs == {frozenset(("peg", g)) for g in others | {"pad_l", "pad_r"}}
    assert m.nmocap == 1 and m.eq_type[0] == mujoco.mjtEq.mjEQ_CONNECT


# States recorded at collection in the quick runs of 2026-12-03 (seed 0) that went NaN,
# each followed by the policy's next four actions. In both the hand is at the table,
# pushing -x with open pads on a peg yawed ~90° that lies against the central wall. With
# 4 Newton iterations the contact force did not converge and launched the peg (13 and 16
# m/s); a few steps later the state was NaN. push: iteration 105, episode 13, step 154
# (its solver warm start was not recorded; the launch happens from a zero one too);
# pick_place: iteration 161, episode 14, step 138 (the launch step: the peg left at 16
# m/s, as in the run).
# fmt: off
LAUNCHES = {
    "push": dict(
        qpos=(
            0.06709099560976028, 0.610151469707489, 0.009778990410268307,  # hand
            0.042646098881959915, 0.04011833667755127,  # fingers
            0.028556358069181442, 0.6324583292007446, 0.03148007020354271,  # peg
            0.700313150882721, 0.056488286703825, -0.05786590650677681, 0.7092405557632446,
        ),
        qvel=(
            0.08690456300973892, -0.4485395848751068, -0.1065836250782013,
            0.10266980528831482, -0.12661133706569672,
            0.40125223994255066, -0.42383110523223877, -0.12783516943454742,
            0.3580007553100586, -0.6543135643005371, -3.1842658519744873,
        ),
        warmstart=(0.0,) * 11,
        mocap=(0.04424033313989639, 0.5952059030532837, 0.009999997913837433),
        ctrl=(0.0379764698445797, 0.0379764698445797),
        actions=(
            (-0.9989893436431885, -0.47458189725875854, -0.4907678961753845, -0.9887891411781311),
            (-0.7860350608825684, -0.5372368693351746, -0.870967447757721, -0.600514829158783),
            (-0.9998630285263062, -0.6327213048934937, -0.969184160232544, -0.6886906623840332),
            (-0.9923322200775146, -0.9808510541915894, -0.6284501552581787, -0.35673531889915466),
        ),
    ),
    "pick_place": dict(
        qpos=(
            0.06833137571811676, 0.6544554233551025, 0.011466569267213345,
            0.04081188142299652, 0.038002945482730865,
            0.029571520164608955, 0.6740821599960327, 0.021964790299534798,
            0.7095954418182373, -0.012008381076157093, -0.0036883032880723476, -0.7044973969459534,
        ),
        qvel=(
            -0.15778665244579315, 0.15243208408355713, -0.017929160967469215,
            -0.04272311180830002, 0.09024173021316528,
            -0.19726572930812836, 0.32758089900016785, -0.07856450974941254,
            2.384986400604248, 0.8199768662452698, 5.096177577972412,
        ),
        warmstart=(
            -94.44469451904297, 9.778375625610352, -28.048521041870117,
            -28.26059913635254, 84.09397888183594,
            -70.12138366699219, 39.648658752441406, -5.374408721923828,
            -1816.3690185546875, 332.07965087890625, 1531.478515625,
        ),
        mocap=(0.03768477588891983, 0.6677343249320984, 0.010000001639127731),
        ctrl=(0.03998887538909912, 0.03998887538909912),
        actions=(
            (-0.9999359846115112, 0.5326576828956604, 0.31793859601020813, -0.9994069337844849),
            (-0.9999830722808838, 0.6372038125991821, -0.9859388470649719, -0.9999025464057922),
            (-1.0, 0.8073751330375671, -0.9877088069915771, -0.9999609589576721),
            (-1.0, 1.0, -1.0, -1.0),
        ),
    ),
}
# fmt: on


@pytest.mark.parametrize("task", TASKS)
def test_peg_pressed_into_wall_is_not_launched(task):
    """A recorded state above, stepped with its recorded actions: the peg, pushed with at
    most ~50 N by a hand moving 1 cm per step, stays below 2 m/s (4 iterations: 13 and 16
    m/s)."""
    env, launch = envs.make(f"sawyer_{task}"), LAUNCHES[task]
    state = env.reset(jax.random.key(0))
    data = state.data.replace(
        qpos=jnp.asarray(launch["qpos"], jnp.float32),
        qvel=jnp.asarray(launch["qvel"], jnp.float32),
        qacc_warmstart=jnp.asarray(launch["warmstart"], jnp.float32),
        mocap_pos=jnp.asarray([launch["mocap"]], jnp.float32),
        ctrl=jnp.asarray(launch["ctrl"], jnp.float32),
    )
    state = state.replace(data=data)
    step = jax.jit(env.step)
    peg = int(env.mj_model.jnt_dofadr[env.mj_model.joint("peg").id])
    speeds = []
    for action in launch["actions"]:
        state = step(state, jnp.asarray(action, jnp.float32))
        speeds.append(float(np.linalg.norm(np.asarray(state.data.qvel)[peg : peg + 3])))
    assert np.isfinite(speeds).all() and max(speeds) < 2.0, speeds


@pytest.mark.parametrize("push", [1.0, -1.0], ids=["apart", "together"])
def test_finger_travel_is_limited(env, push):
    """50 N on each finger (5x its actuator's cap) holds the opening in [0, 0.08] to 1 mm
    once settled (a step force on a 20 g finger overshoots for a few steps): a peg yawing
    between open pads once wedged unlimited fingers 27 mm apart."""
    m = env.mj_model
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, m.key("home").id)
    peg = int(m.jnt_qposadr[m.joint("peg").id])
    d.qpos[peg : peg + 2] = (0.0, 0.4)  # out from between the pads
    for name, outward in (("finger_l", -1.0), ("finger_r", 1.0)):
        d.xfrc_applied[m.body(name).id, 1] = 50.0 * push * outward
    openings = []
    for _ in range(400):  # 1 s
        mujoco.mj_step(m, d)
        openings.append(float(env.finger_opening(d)))
    settled = np.array(openings[-100:])  # the last 0.25 s
    assert (settled > -1e-3).all() and (settled < 2 * sawyer_peg.FINGER_OPEN + 1e-3).all()


def test_reset_start_state_and_noise(env):
    keys = jax.random.split(jax.random.key(1), 256)
    state = jax.jit(jax.vmap(env.reset))(keys)
    obs = np.asarray(state.obs)
    np.testing.assert_allclose(obs[:, :3], np.broadcast_to(HAND_START, (256, 3)), atol=1e-6)
    np.testing.assert_allclose(obs[:, 3], 0.08, atol=1e-6)  # open
    noise = obs[:, 4:6] - [0.4, 0.8]
    assert np.abs(noise).max() <= 0.02 and noise.std(0).min() > 0.008  # ~U[-0.02, 0.02]
    np.testing.assert_allclose(obs[:, 6], 0.02, atol=1e-6)  # resting on the table
    np.testing.assert_array_equal(state.achieved_goal, obs[:, 4:])
    np.testing.assert_allclose(np.asarray(state.data.mocap_pos)[:, 0], obs[:, :3], atol=1e-6)
    goals = np.asarray(state.goal)
    assert all(np.abs(env.goal_points - g).sum(-1).min() == 0 for g in goals)
    assert not np.asarray(state.success).any()  # every goal is > 0.05 from the start


def test_clip_goal_and_uniform_goals(env):
    goals = jnp.array([[-1.0, 0.0, 0.5], [0.1, 0.5, 0.1]])
    clipped = np.asarray(env.clip_goal(goals))
    z = [0.02, 0.02] if env.task == "push" else [0.3, 0.1]
    np.testing.assert_allclose(clipped, [[-0.6, 0.2, z[0]], [0.1, 0.5, z[1]]], atol=1e-7)
    u = np.asarray(env.sample_uniform_goals(jax.random.key(0), 1000))
    assert (u >= env.goal_low - 1e-7).all() and (u <= env.goal_high + 1e-7).all()
    if env.task == "push":
        np.testing.assert_allclose(u[:, 2], 0.02)
    else:
        assert u[:, 2].std() > 0.05
    np.testing.assert_allclose(env.clip_goal(env.goal_points), env.goal_points)


def test_normalize_obs_and_goal(env):
    low = np.r_[HAND_LOW, 0.0, env.goal_low]
    high = np.r_[HAND_HIGH, 0.08, env.goal_high]
    np.testing.assert_allclose(env.normalize_obs(jnp.asarray(low)), -np.ones(7), atol=1e-6)
    np.testing.assert_allclose(env.normalize_obs(jnp.asarray(high)), np.ones(7), atol=1e-6)
    batch = jnp.stack([low, high, (low + high) / 2])
    np.testing.assert_allclose(env.normalize_obs(batch)[2], np.zeros(7), atol=1e-6)
    np.testing.assert_allclose(env.normalize_goal(env.goal_high), np.ones(3), atol=1e-6)


# --- physics: one compiled rollout per task ------------------------------------------------
def test_rollout_contract_shapes_and_finite(run):
    """reset/step under jit + vmap (+ scan): EnvState shapes and dtypes, finite values."""
    n, env, final = len(run["modes"]), run["env"], run["final"]
    chex.assert_shape(final.obs, (n, 7))
    chex.assert_shape([final.achieved_goal, final.goal], (n, 3))
    chex.assert_shape(final.success, (n,))
    chex.assert_shape(final.data.qpos, (n, env.mj_model.nq))
    chex.assert_shape(final.data.mocap_pos, (n, 1, 3))
    assert final.obs.dtype == jnp.float32 and final.success.dtype == jnp.bool_
    np.testing.assert_array_equal(final.obs, run["obs"][-1])
    np.testing.assert_array_equal(final.achieved_goal, run["obs"][-1, :, 4:])
    np.testing.assert_array_equal(env.goal_of_obs(final.obs), final.achieved_goal)
    np.testing.assert_array_equal(final.goal, run["goals"])  # step keeps the goal
    chex.assert_shape(run["obs"], (H, n, 7))
    chex.assert_shape(run["success"], (H, n))
    assert np.isfinite(run["obs"]).all() and np.isfinite(run["peg_vel"]).all()


def _assert_same_run(record):
    """A second call with the same key reuses the compiled rollout (assert_max_traces(n=1)
    on reset and step would raise on a retrace) and reproduces the run bit for bit."""
    _, (obs, success, peg_vel) = record["rollout"](jax.random.key(0), *record["inputs"])
    np.testing.assert_array_equal(np.asarray(obs), record["obs"])
    np.testing.assert_array_equal(np.asarray(success), record["success"])
    np.testing.assert_array_equal(np.asarray(peg_vel), record["peg_vel"])


def test_same_key_same_trajectory_no_retrace(pick_place_run):
    _assert_same_run(pick_place_run)


@pytest.mark.slow
def test_same_key_same_trajectory_no_retrace_push(push_run):
    _assert_same_run(push_run)


def test_pick_place_scripted_reaches_every_goal(pick_place_run):
    """Over the peg, descend, close, lift to 0.2, carry (over the wall), release."""
    r = pick_place_run
    for i in np.nonzero(r["modes"] == SCRIPT)[0]:
        goal = r["goals"][i]
        t = _first_success(r, i)
        assert t is not None and t < H, f"goal {goal}: no success in {H} steps"
        print(f"pick & place goal {goal}: success at step {t + 1}")
        peg = r["obs"][:, i, 4:]
        if goal[0] < 0:  # across the central wall: lifted over its top (0.1)
            assert peg[:, 2].max() > 0.15 and peg[-1, 0] < 0
        # Released: open fingers, the peg dropped back onto the table.
        assert r["obs"][-1, i, 3] > 0.07
        np.testing.assert_allclose(peg[-1, 2], 0.02, atol=3e-3)


@pytest.mark.slow  # the push rollout is compiled only under slow (see `run`)
def test_push_scripted_reaches_goal(push_run):
    r = push_run
    (i,) = np.nonzero(r["modes"] == SCRIPT)[0]
    np.testing.assert_allclose(r["goals"][i], [0.4, 0.4, 0.02])
    t = _first_success(r, i)
    assert t is not None and t < H
    print(f"push goal {r['goals'][i]}: success at step {t + 1}")
    assert r["obs"][:, i, 6].max() < 0.03  # pushed, never lifted


def test_peg_cannot_pass_central_wall(run):
    """Closed gripper shoves the peg into the wall's +x face at full speed for ~100 steps."""
    face = 0.01  # the wall's +x face
    for i in np.nonzero(run["modes"] == WALL)[0]:
        peg_x, peg_z = run["obs"][:, i, 4], run["obs"][:, i, 6]
        hand_x = run["obs"][-1, i, 0]
        assert peg_x.min() > face + 0.06 - 0.003  # end face on the wall, < 3 mm in
        assert peg_x[-1] < 0.08  # it did reach the wall ...
        assert peg_z.max() < 0.05  # ... without popping up
        assert hand_x > peg_x[-1] + 0.06  # and the hand stayed behind it


def test_peg_pinned_on_back_wall_cannot_be_raised_above_it(run):
    """A pad presses the peg onto the 0.06-high back wall and climbs to the hand's ceiling.
    While that wall was a half-space plane (a wall of unbounded height) the pad's friction
    carried the peg up the wall with it to the ceiling (z = 0.50), a lift a learned policy
    found and used (docs/DEVIATIONS.md, "The Sawyer table's retaining walls"). Now the peg
    cannot be raised that way: it tips over the wall's top and falls off the table."""
    (i,) = np.nonzero(run["modes"] == PIN)[0]
    hand, peg = run["obs"][:, i, :3], run["obs"][:, i, 4:]
    assert peg[:, 1].max() > 0.97  # the peg did reach the wall (its face at y = 1.0) ...
    assert hand[-1, 2] > 0.45  # ... and the pad climbed past it to the ceiling
    # At most as high as the peg standing on its end on the wall's top (0.06 + 0.06) ...
    assert peg[:, 2].max() < 0.13
    # ... as it tips over, and it ends lying beyond the wall (outer face at y = 1.02).
    np.testing.assert_allclose(peg[-1, 2], 0.02, atol=0.005)
    assert peg[-1, 1] > 1.02 + 0.02


def test_hand_moves_one_centimetre_per_step_within_bounds(run):
    (i,) = np.nonzero(run["modes"] == CONST)[0]
    hand = run["obs"][:, i, :3]
    expected = HAND_START + sawyer_peg.MOVE_SCALE * CONST_STEPS * np.array(CONST_ACTION[:3])
    # The hand trails its target by ~0.014 m at full speed (critically damped, 0.01 s).
    np.testing.assert_allclose(hand[CONST_STEPS - 1], expected, atol=0.02)
    step = np.abs(np.diff(hand[CONST_STEPS - 5 : CONST_STEPS], axis=0))
    np.testing.assert_allclose(step, 0.01, atol=1e-3)  # steady speed: exactly 0.01 a
    np.testing.assert_allclose(hand[-1], [-0.5, 0.25, 0.5], atol=2e-3)  # held at the bounds
    np.testing.assert_allclose(run["obs"][-1, i, 3], 0.08, atol=1e-3)  # grip -1: open


def test_random_steps_keep_peg_on_table(run):
    """10,000 uniform random steps + 5,000 random steps drifting toward the peg."""
    rand = np.isin(run["modes"], (RANDOM, SEEK))
    obs, vel = run["obs"][:, rand], run["peg_vel"][:, rand]
    assert np.isfinite(obs).all() and np.isfinite(vel).all()
    peg = obs[..., 4:]
    assert (np.abs(peg[..., 0]) < 0.7).all() and ((peg[..., 1] > 0.2) & (peg[..., 1] < 1.0)).all()
    assert peg[..., 2].min() > 0.01  # never more than 1 cm into the table
    assert peg[..., 2].max() < 0.5
    assert np.linalg.norm(vel[..., :3], axis=-1).max() < 5.0  # m/s
    assert np.linalg.norm(vel[..., 3:], axis=-1).max() < 150.0  # rad/s
    hand = obs[..., :3]
    assert (hand > HAND_LOW - 0.01).all() and (hand < HAND_HIGH + 0.01).all()
    # The fingers' travel limits hold through these contact-rich steps: the opening stays in
    # [0, 0.08] to 1 mm.
    assert (obs[..., 3] > -0.001).all() and (obs[..., 3] < 0.081).all()
    assert np.abs(np.asarray(run["env"].normalize_obs(obs))).max() < 1.2
    # The drifting envs really handle the peg: it moves, gets lifted, gets pinched.
    seek_peg = run["obs"][:, run["modes"] == SEEK, 4:]
    assert np.abs(seek_peg[-1, :, :2] - seek_peg[0, :, :2]).max() > 0.05
    assert seek_peg[..., 2].max() > 0.05
