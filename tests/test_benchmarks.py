"""The benchmark's own arithmetic (the SAC update's FLOP count, the results file, the
paired ratio) and the brax SAC timing harness."""

import functools
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from benchmarks import results, sac_update


def test_update_flops_by_hand():
    # hidden (4,), batch 1; actor 8 -> 4 -> 4 (2 x 2 actions), critic 10 -> 4 -> 1.
    # MACs: actor 8*4 + 4*4 = 48 (first layer 32); critic 10*4 + 4*1 = 44 (first 40).
    critic_step = 48 + 2 * 44 + 2 * (3 * 44 - 40)  # target actor, target twin, twin fwd+bwd
    actor_step = 48 + 2 * 44 + 2 * 44 + (2 * 48 - 32)  # actor, twin, twin input grads, actor bwd
    assert sac_update.update_flops((4,), 1, 1) == 2 * (critic_step + actor_step)
    assert sac_update.update_flops((4,), 1, 2) == 2 * (critic_step + actor_step / 2)


def test_update_flops_paper_size_matches_the_issue_count():
    # 3x512, batch 512, twin Q: about 8.7 GFLOP with the actor every update, 6.8 every 2nd.
    assert sac_update.update_flops((512,) * 3, 512, 1) / 1e9 == pytest.approx(8.67, abs=0.01)
    assert sac_update.update_flops((512,) * 3, 512, 2) / 1e9 == pytest.approx(6.77, abs=0.01)


@functools.cache
def small_update_xla_flops(layer_norm: bool = False) -> float:
    """XLA's FLOP count of the compiled small-size update (actor every update), compiled
    once per `layer_norm` for the tests below."""
    return sac_update.jax_update_rate(
        "small", 1, n_updates=1, time_it=False, layer_norm=layer_norm
    )[1]


def test_update_flops_agree_with_xla_cost_analysis():
    """XLA's count of the compiled update (matmuls + elementwise) is within 3% above ours."""
    xla = small_update_xla_flops()
    ours = sac_update.update_flops(*sac_update.SIZES["small"], 1)
    assert 1.0 <= xla / ours < 1.03, (xla, ours)


def test_critic_layer_norm_adds_little_arithmetic_to_the_update():
    """LayerNorm is a few elementwise operations per hidden unit of each critic (forward and
    backward), where a unit's matmul costs 2 x fan-in FLOPs: XLA counts more FLOPs with it,
    but under 10% more at the small size (its cost on a CPU is memory traffic, measured by
    `python -m benchmarks.sac_update --layer-norm-cost`)."""
    plain, with_ln = small_update_xla_flops(), small_update_xla_flops(layer_norm=True)
    assert 1.0 < with_ln / plain < 1.1, (plain, with_ln)


def test_critic_probe_already_reached_share_by_hand():
    """phi moves 1 per step over H = 5 steps, radius 2.5: the future goal t' is within the
    radius iff t' - t <= 2, a share of 2/5, 2/4, 2/3, 1 and 1 at t = 0..4; mean 0.7133.
    A still episode's future goals are all within it."""
    from benchmarks import critic_probe

    moving = np.stack([np.arange(6.0), np.zeros(6)], -1)[None]  # (1, H + 1, 2)
    share = critic_probe.already_reached_share(moving, 2.5, draws=200_000)
    np.testing.assert_allclose(share, (2 / 5 + 2 / 4 + 2 / 3 + 1 + 1) / 5, atol=0.005)
    assert critic_probe.already_reached_share(np.zeros((3, 6, 2)), 0.1, draws=1000) == 1.0


def test_write_section_replaces_in_place(tmp_path):
    path = tmp_path / "RESULTS.md"
    results.write_section("A", "one", path)
    results.write_section("B", "two", path)
    results.write_section("A", "three", path)
    text = path.read_text()
    assert text.count("## A") == 1 and "three" in text and "one" not in text
    assert text.index("## A") < text.index("## B")
    np.testing.assert_equal(text.endswith("two\n"), True)


def test_visit_map_counts_points_per_cell_by_hand():
    from benchmarks import visit_map

    layout = ("#####", "#.S.#", "#####")  # start cell (1, 2) at the origin, cells 4 wide
    points = np.array([[0.0, 0.0], [1.9, -1.9], [-4.0, 0.5], [-2.1, 0.0], [4.0, 0.0], [50, 0]])
    counts = visit_map.grid_counts(visit_map.layout_grid(layout, 4.0), points)
    want = np.zeros((3, 5), int)
    want[1, 2], want[1, 1], want[1, 3] = 2, 2, 1  # the point at x = 50 is off the map
    np.testing.assert_array_equal(counts, want)
    assert visit_map.draw_counts(layout, counts * 50) == ["#####", "#221#", "#####"]  # 100, 50
    scores = np.full((3, 5), 0.05)
    scores[1, 3] = 0.97
    assert visit_map.draw_scores(layout, scores, [(1, 1)])[1] == "0m090"


def test_visit_map_goal_counts_per_mode_by_hand():
    """Slot j serves mode j mod n_modes; counts are drawn 1-9, `+` from 10, layout elsewhere."""
    from benchmarks import visit_map

    layout = ("#####", "#.S.#", "#####")
    grid = visit_map.layout_grid(layout, 4.0)
    # cells of row 1 have centres x = -4, 0, 4 (y = 0); slots alternate modes 0 and 1
    goals = np.array([[-4.0, 0.0], [4.0, 0.5], [-3.0, 1.0], [0.0, 0.0]] + [[-4.0, 0.0]] * 10)
    per_mode = visit_map.goal_counts_per_mode(grid, goals, 2)
    assert per_mode[0][1].tolist() == [0, 7, 0, 0, 0]  # slots 0, 2, 4, ..., 12: all at x = -4
    assert per_mode[1][1].tolist() == [0, 5, 1, 1, 0]  # slots 1 (x 4), 3 (x 0), 5-13 (x -4)
    assert visit_map.draw_goal_counts(layout, per_mode[1])[1] == "#511#"
    assert visit_map.draw_goal_counts(layout, per_mode[0] * 2) == ["#####", "#+S.#", "#####"]


def test_visit_map_her_goals_from_start_by_hand():
    """H = 2, phi(s) = x: 0.5, 0.5, then 4.5 (one cell right). Both transitions start in
    the start cell. t = 0 draws t' in {1, 2} (0.8 / 2 each), t = 1 draws t' = 2 (0.8):
    per transition 0.2 goals in the start cell and 0.6 in the next. With a minimum
    distance of 1, t = 0's t' = 1 (not moved) is dropped: 0 and 0.6."""
    from benchmarks import visit_map

    layout = ("#####", "#.S.#", "#####")
    grid = visit_map.layout_grid(layout, 4.0)
    achieved = np.array([[[0.5, 0.0], [0.5, 0.0], [4.5, 0.0]]])
    per = visit_map.her_goals_from_start(grid, achieved, 0.8, 0.0)
    want = np.zeros((3, 5))
    want[1, 2], want[1, 3] = 0.2, 0.6
    np.testing.assert_allclose(per, want)
    want[1, 2] = 0.0
    np.testing.assert_allclose(visit_map.her_goals_from_start(grid, achieved, 0.8, 1.0), want)
    # A second episode starts a cell to the left and moves into S's cell at t = 1: only
    # its t = 0 starts in its own start cell, with both futures (0.4 each) in S's cell.
    # Three transitions in all: 1.2 / 3 goals in the right cell, 0.8 / 3 in S's.
    other = np.array([[[-4.5, 0.0], [0.5, 0.0], [0.5, 0.0]]])
    both = np.concatenate([achieved, other])
    want[1, 2], want[1, 3] = 0.8 / 3, 1.2 / 3
    np.testing.assert_allclose(visit_map.her_goals_from_start(grid, both, 0.8, 1.0, chunk=1), want)


def test_profile_table_shares_add_up_by_hand():
    """Each part's share is its time over the whole; "other" is what the parts miss; the
    evaluation's share is also over the train step's whole."""
    from benchmarks import profile
    from d2c_jax import config
    from d2c_jax.training import agent as agent_lib

    sched = agent_lib.make_schedule(config.preset("medium_maze", "quick"), horizon=100)
    parts = {"env steps": 0.5, "SAC updates": 1.0}
    row = {"env": "m", "parts": parts, "whole": 2.0, "other": 0.5, "evaluation": 0.4}
    row["env_steps_per_s"] = 1000.0
    table = profile.profile_table([{**row, "schedule": sched}])
    last = table.splitlines()[-1]
    assert "500 ms (25%)" in last and "1000 ms (50%)" in last
    assert last.endswith("| 500 ms | 2.00 s | 400 ms (20%) | 1000 |")
    # E = 20 x 100, M = E / 4, C = 16, an evaluation every 10k env steps = 5 iterations
    assert "| m | 2000 / 500 / 16 / 5 |" in last


def test_visit_map_head_maps_put_each_head_on_its_cell():
    """head_maps[i, r, c] is head i's f_i at the centre of cell (r, c), for any net."""
    import jax

    from benchmarks import visit_map
    from d2c_jax.curricula import classifier
    from envs import layouts

    layout = ("#####", "#.S.#", "#...#", "#####")
    net = classifier.Classifier(
        n_heads=3, hidden_sizes=(8,), goal_low=(-8.0, -8.0), goal_high=(8.0, 8.0)
    )
    params = net.init(jax.random.key(0), np.zeros((1, 2)), np.zeros((1, 2)))
    goal = np.array([4.0, -4.0], np.float32)
    maps = visit_map.head_maps(net, params, visit_map.layout_grid(layout, 4.0), goal)
    assert maps.shape == (3, 4, 5)
    centre = layouts.cell_center(layout, (2, 3), 4.0)
    want = np.asarray(classifier.head_probs(net, params, centre[None], goal[None]))[0]
    np.testing.assert_allclose(maps[:, 2, 3], want, rtol=1e-6)
    assert len(set(np.round(maps[0].ravel(), 6))) > 1  # cells differ: no constant map


def test_visit_map_table_grid_by_hand():
    """Sawyer's table in 0.1 squares: 12 x 8 over x in [-0.6, 0.6], y in [0.2, 1.0]; the
    central wall's squares are '#'; points land in the square that holds them."""
    import envs
    from benchmarks import visit_map

    env = envs.make("sawyer_push")
    grid = visit_map.table_grid(env)
    assert len(grid.layout) == 8 and len(grid.layout[0]) == 12
    # The wall (x in [-0.01, 0.01], y in [0.35, 0.85]) holds no square centre (they sit at
    # x = -0.05 and 0.05), so the map has no '#'.
    assert "#" not in "".join(grid.layout)
    np.testing.assert_allclose(grid.centres[0], [-0.55, 0.95, 0.02], atol=1e-6)
    points = np.array([[0.42, 0.78], [0.45, 0.75], [-0.55, 0.25], [0.7, 0.5]])
    counts = visit_map.grid_counts(grid, points)
    assert counts[2, 10] == 2 and counts[7, 0] == 1 and counts.sum() == 3  # x = 0.7 is off

    class Boxed:
        goal_low, goal_high = np.array([0.0, 0.0, 0.0]), np.array([0.4, 0.2, 0.0])
        goal_points = np.zeros((1, 3))
        obstacles_xy = (np.array([[0.15, 0.05]]), np.array([[0.11, 0.04]]))  # x 0.04-0.26

    assert visit_map.table_grid(Boxed()).layout == ("....", "###.")


def test_reward_probe_reports_every_distance_and_all_pairs(tmp_path, capsys):
    """On a tiny run: one line per radius and per band, and the bands hold every pair;
    visit_map's command line draws its maps (layout-shaped rows) of the same run."""
    from benchmarks import reward_probe, visit_map
    from d2c_jax.training import cli, loop, runs

    cfg, _, _ = cli.parse_args(["--env", "medium_maze", "--preset", "tiny"])
    assert loop.train(cfg, tmp_path / "run", quiet=True) == 0
    cfg, env, ts = runs.load_run(tmp_path / "run")
    ts = jax.tree.map(lambda x: x[0], ts)
    lines = reward_probe.probe(cfg, env, ts, 500, jax.random.key(0))
    assert len(lines) == 1 + len(reward_probe.RADII) + len(reward_probe.BANDS)
    pairs = [int(line.split(": ")[1].split(" pairs")[0]) for line in lines[-5:]]
    assert sum(pairs) == 500
    assert reward_probe.main([str(tmp_path / "missing")]) == 2
    capsys.readouterr()
    assert visit_map.main([str(tmp_path / "run"), "--her-goals"]) == 0
    lines = capsys.readouterr().out.splitlines()
    width = len(env.layout[0])
    her = lines[lines.index(next(x for x in lines if x.startswith("HER future goals"))) + 1 :]
    assert len(her) == len(env.layout) and all(len(x) == 2 * width + 3 for x in her)
    assert her[0] == "#" * width + "   " + "#" * width  # the outer wall
    # --rematch: each map block holds the K goals, K / n_modes per mode's map.
    assert visit_map.main([str(tmp_path / "run"), "--rematch", "0", "1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    heads = [i for i, x in enumerate(lines) if x.startswith("goals per cell, re-matched")]
    assert len(heads) == 2 * 3 and "beta 1," in lines[heads[-1]]
    k, n_modes = cfg.curriculum.n_slots, env.n_modes
    for i in heads:
        maps = [row.split("   ") for row in lines[i + 1 : i + 1 + len(env.layout)]]
        # the tiny preset has fewer than 10 slots per mode, so every count is one digit
        per_mode = [
            sum(int(ch) for row in maps for ch in row[m] if ch.isdigit()) for m in range(n_modes)
        ]
        assert per_mode == [k // n_modes] * n_modes, (lines[i], maps)


def test_paired_ratio_is_the_median_of_back_to_back_ratios_by_hand():
    # Pairs: 60/200 = 0.3, 60/50 = 1.2, 80/100 = 0.8 -> median 0.8 (best/best would be 0.4).
    assert results.paired_ratio([60.0, 60.0, 80.0], [200.0, 50.0, 100.0]) == pytest.approx(0.8)
    with pytest.raises(ValueError):
        results.paired_ratio([1.0, 2.0], [1.0])


@pytest.mark.slow  # 15-25 s: compiles brax SAC's epoch; the adapter's default test runs brax SAC
def test_brax_sac_epochs_alternate_with_the_callback():
    """brax SAC trains on our maze through the adapter; the callback runs once before each
    timed epoch, and the compiling epoch is not reported."""
    from benchmarks import brax_sac

    calls = []
    rates = brax_sac.epoch_rates(
        "small", timed_epochs=2, after_epoch=lambda: calls.append(1), steps_per_epoch=3
    )
    assert len(calls) == 2 and len(rates) == 2
    assert all(np.isfinite(r) and r > 0 for r in rates)


def test_update_flops_counts_a_matmul_at_two_per_multiply_add():
    """`brax_sac.update_flops` on an "update" that is one (8, 16) x (16, 4) matmul: XLA's
    cost analysis gives 2 x 8 x 16 x 4 = 1,024 FLOPs (hand-computed)."""
    import jax
    import jax.numpy as jnp

    from benchmarks import brax_sac

    weights = jnp.ones((16, 4))
    update = lambda x, key: (x[:, :16] @ weights, None)  # noqa: E731
    flops = brax_sac.update_flops(update, jnp.ones((8, 16)), jax.random.key(0))
    assert flops == 2 * 8 * 16 * 4


def test_visit_map_reach_rates_of_a_policy_that_never_moves():
    """A policy that never moves reaches only the start cell's centre (the reset lies
    within 0.1 x sqrt 2 of it, inside the 0.5 radius); walls are NaN and drawn '#'."""
    import jax
    import jax.numpy as jnp

    import envs
    from benchmarks import visit_map

    env = envs.make("medium_maze")
    grid = visit_map.env_grid(env)
    still = lambda obs, goal, key: jnp.zeros(env.action_dim)  # noqa: E731
    rates, standing = visit_map.reach_rates(env, still, grid, 2, jax.random.key(0))
    walls = np.array([[ch == "#" for ch in row] for row in env.layout])
    np.testing.assert_array_equal(np.isnan(rates), walls)
    want = np.where(walls, np.nan, 0.0)
    want[5, 5] = 1.0  # S
    np.testing.assert_array_equal(rates, want)
    np.testing.assert_array_equal(standing, np.where(walls, np.nan, 1.0))  # for every goal
    assert visit_map.draw_reach(rates)[5] == "#0000A0000#"
    assert visit_map.draw_reach(np.array([[0.35, np.nan, 0.99]])) == ["3#9"]


def test_visit_map_reach_rates_of_a_policy_that_runs_right(medium_maze):
    """Full speed along +x from the start: it never stands still, and it reaches the four
    corridor cells to its right (x = 4..16) and no other; not even S, which it has left
    after the first step (success is read after each step, SPEC §7)."""
    import jax
    import jax.numpy as jnp

    from benchmarks import visit_map

    go_right = lambda obs, goal, key: jnp.array([1.0, -obs[2]])  # noqa: E731
    grid = visit_map.env_grid(medium_maze)
    rates, standing = visit_map.reach_rates(medium_maze, go_right, grid, 1, jax.random.key(0))
    walls = np.array([[ch == "#" for ch in row] for row in medium_maze.layout])
    want = np.where(walls, np.nan, 0.0)
    want[5, 6:10] = 1.0
    np.testing.assert_array_equal(rates, want)
    np.testing.assert_array_equal(standing, np.where(walls, np.nan, 0.0))


def test_ant_gait_cpg_action_by_hand_and_bad_input(capsys):
    """a_j(t) = clip(A_j sin(w t dt + phi_j) + c_j, -1, 1), by hand at t = 0 and t = 1; bad
    counts exit 2 with a first line that names the flag."""
    from benchmarks import ant_gait

    w = np.pi / 2 / ant_gait.ENV_DT  # a quarter period per env step
    gait = np.concatenate([[w], np.full(8, 2.0), np.zeros(8), np.full(8, 0.25)])
    np.testing.assert_allclose(ant_gait.cpg_action(gait, 0), np.full(8, 0.25))  # sin 0 = 0
    np.testing.assert_allclose(ant_gait.cpg_action(gait, 1), np.ones(8))  # 2 + 0.25, clipped
    assert ant_gait.main(["--draws", "0"]) == 2
    assert capsys.readouterr().err.splitlines()[0] == "error: --draws must be >= 1, got 0"
    assert ant_gait.main(["--search-physics", "verlet"]) == 2


def test_throughput_section_without_sb3_reads_n_a_against_sb3(monkeypatch):
    """`benchmarks.run --only throughput --no-sb3` (a GPU image without the bench extra):
    no SB3 row, "n/a" in the vs-SB3 column, the ratios to brax by hand."""
    from benchmarks import run

    def rates(size, with_sb3):
        assert not with_sb3
        return run.Throughput(
            {run.BRAX: (200.0, 200.0), "d2c_jax SAC+HER": (250.0, 250.0)},
            {"d2c_jax SAC+HER": 1.2},
        )

    monkeypatch.setattr(run, "throughput_rates", rates)
    text = run.throughput_section(with_sb3=False)
    assert run.SB3 not in text and "--no-sb3" in text
    ours = [ln for ln in text.splitlines() if "| d2c_jax SAC+HER |" in ln]
    assert len(ours) == len(run.TARGET_VS_SB3)
    assert all("| 250.0 | 250.0 | n/a | 1.25x | 1.20x |" in ln for ln in ours)


@pytest.mark.parametrize("argv", [["--epochs", "0"], ["--variants", "0", "2"]])
def test_update_loop_refuses_counts_below_one(argv, capsys):
    from benchmarks import update_loop

    assert update_loop.main(argv) == 2
    assert capsys.readouterr().err.splitlines()[0] == (
        "error: --epochs and every --variants value must be >= 1"
    )


def test_update_order_refuses_epochs_below_one(capsys):
    from benchmarks import update_order

    assert update_order.main(["--epochs", "0"]) == 2
    assert capsys.readouterr().err.splitlines()[0] == "error: --epochs must be >= 1"


def test_update_order_simultaneous_block_steps_both_from_the_old_parameters():
    """brax's order: the critic step is ours bitwise (same state, same key); the actor step
    is taken against the pre-update critic, so it differs from ours, which sees the
    updated one, and equals `_actor_step` on the old state."""
    import chex

    from benchmarks import update_order
    from d2c_jax.config import SACConfig
    from d2c_jax.core import networks, sac

    class Env:
        obs_dim, action_dim, goal_dim = 3, 2, 2
        goal_low, goal_high = np.array([-1.0, -1.0]), np.array([1.0, 1.0])
        normalize_obs = staticmethod(lambda obs: obs)
        normalize_goal = staticmethod(lambda goal: goal)

    env = Env()
    cfg = SACConfig(
        hidden_sizes=(16, 16), batch_size=8, actor_update_every=1, target_update_every=1
    )
    nets, opt, hp = networks.make_networks(cfg, env), sac.make_optimizers(), sac.hyperparams(cfg)
    state = sac.init_sac(nets, opt, env, hp, jax.random.key(0))
    batch = sac_update.random_batch(env, 8, 1, seed=1)  # one block of one batch of 8
    key = jax.random.key(2)
    ours, _ = sac.update_sac_block(cfg, nets, opt, hp, state, batch, env, key)
    brax_order, _ = update_order.simultaneous_block(cfg, nets, opt, hp, state, batch, env, key)
    chex.assert_trees_all_equal(brax_order.critic_params, ours.critic_params)
    chex.assert_trees_all_equal(brax_order.target_critic_params, ours.target_critic_params)
    key_actor = jax.random.split(jax.random.split(key, 1)[0])[1]
    feats = networks.actor_input(env, batch.obs[0], batch.goal[0])
    acted = sac._actor_step(cfg, nets, opt, hp, state, feats, env.action_dim, key_actor)
    chex.assert_trees_all_equal(brax_order.actor_params, acted.actor_params)
    chex.assert_trees_all_equal(brax_order.log_alpha, acted.log_alpha)
    differs = jax.tree.map(
        lambda a, b: bool(jnp.any(a != b)), brax_order.actor_params, ours.actor_params
    )
    assert any(jax.tree.leaves(differs))


def test_goal_probe_parses_points_and_rejects_bad_input(capsys):
    from benchmarks import goal_probe

    np.testing.assert_array_equal(goal_probe.parse_points("4,0;-4,0.5"), [[4, 0], [-4, 0.5]])
    for text in ("a,b", "1,2;3", "1,nan", ""):
        with pytest.raises(ValueError, match="goal points must"):
            goal_probe.parse_points(text)
    assert goal_probe.main(["1,2"]) == 2  # no "--"
    assert goal_probe.main(["x", "--", "--env", "medium_maze"]) == 2
    assert capsys.readouterr().err.splitlines()[-1].startswith("error: goal points must")


@pytest.mark.slow
def test_goal_probe_trains_and_evaluates_on_the_moved_points(tmp_path):
    """A tiny medium_maze run with its goal points moved to two cells beside the start:
    the run evaluates exactly those two modes, records them, and its curriculum distance
    is measured to them (3.7 from the start's neighbourhood, not the real modes' 22)."""
    import json

    import envs
    from benchmarks import goal_probe

    out = tmp_path / "probe"
    make = envs.make
    try:
        args = ["4,0;-4,0", "--", "--env", "medium_maze", "--preset", "tiny", "--out", str(out)]
        assert goal_probe.main(args) == 0
    finally:
        envs.make = make  # the probe patches the module for its process
    rows = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    last = rows[-1]
    assert sorted(k for k in last if k.startswith("eval/success/")) == [
        "eval/success/0", "eval/success/1"
    ]  # fmt: skip
    assert last["curriculum/distance"] < 6.0
    saved = json.loads((out / goal_probe.PROBE_FILE).read_text())
    assert saved == {"goal_points": [[4.0, 0.0], [-4.0, 0.0]]}


def test_actor_probe_action_stats_by_hand():
    from benchmarks import actor_probe

    # 2 episodes, 3 steps, 2 components: episode 0 holds (1, 0); episode 1 varies.
    actions = np.array([[[1.0, 0.0]] * 3, [[0.0, -0.96], [0.0, 0.0], [0.0, 0.96]]])
    stats = actor_probe.action_stats(actions)
    assert stats.saturated == 5 / 12  # the three 1.0s and both +-0.96s
    np.testing.assert_allclose(stats.std_over_time, np.sqrt(2 * 0.96**2 / 3) / 4)


def test_actor_probe_of_a_policy_that_runs_right(medium_maze):
    """Full speed along +x (as in the reach-map test): it reaches (8, 0) at step 8 and not
    (0, 8), runs 17.6 - x_0 units to the wall's clearance, and holds a saturated first component
    for the whole episode."""
    import jax
    import jax.numpy as jnp

    from benchmarks import actor_probe

    go_right = lambda obs, goal, key: jnp.array([1.0, -obs[2]])  # noqa: E731
    u = lambda obs, goal: jnp.array([3.0, -4.0])  # noqa: E731
    goals = np.array([[8.0, 0.0], [0.0, 8.0]])
    rows = actor_probe.probe(medium_maze, go_right, u, goals, 2, jax.random.key(0))
    assert [r.reach for r in rows] == [1.0, 0.0]
    # x_0 + k >= 7.5 first at k = 8 for x_0 in [-0.1, 0.1]; never for the other goal.
    assert rows[0].steps == 8 and np.isnan(rows[1].steps)
    for r in rows:
        assert 17.5 <= r.path <= 17.7  # the reset's x lies in [-0.1, 0.1]
        assert r.stats.saturated == 0.5
        assert r.stats.std_over_time < 0.01  # only the first step turns, by at most 0.1
        assert (r.u_max, r.u_mean) == (4.0, 3.5)
    assert len(actor_probe.format_rows(rows)) == 3


def test_actor_probe_route_of_a_policy_that_runs_right(medium_maze):
    """Full speed along +x through waypoints (4, 0), (8, 0), (8, 8): it arrives at the first
    at step 4 (x_0 + k >= 3.5 first at k = 4 for x_0 in [-0.1, 0.1]) and, switching goals
    there, at the second at step 8; never at the third, off its line."""
    import jax
    import jax.numpy as jnp

    from benchmarks import actor_probe

    go_right = lambda obs, goal, key: jnp.array([1.0, -obs[2]])  # noqa: E731
    route = np.array([[4.0, 0.0], [8.0, 0.0], [8.0, 8.0]])
    rows = actor_probe.probe_route(medium_maze, go_right, route, 2, jax.random.key(0))
    assert [r.reach for r in rows] == [1.0, 1.0, 0.0]
    assert rows[0].step == 4 and rows[1].step == 8 and np.isnan(rows[2].step)
    assert len(actor_probe.format_route_rows(rows)) == 4


def test_actor_probe_route_switch_and_check_by_hand():
    import jax.numpy as jnp

    from benchmarks import actor_probe

    route = jnp.array([[0.0, 0.0], [4.0, 0.0], [4.0, 4.0]])
    switch = actor_probe.route_switch(route)
    # Near a waypoint: the next one; near the last: the last again.
    np.testing.assert_array_equal(switch(jnp.array([0.3, 0.2]), None), [4.0, 0.0])
    np.testing.assert_array_equal(switch(jnp.array([4.2, 0.1]), None), [4.0, 4.0])
    np.testing.assert_array_equal(switch(jnp.array([3.9, 4.4]), None), [4.0, 4.0])
    actor_probe.check_route(np.asarray(route), radius=1.9)  # gaps 4, 4, 5.66 > 3.8
    with pytest.raises(ValueError, match="waypoints 0 and 1 are 4 apart"):
        actor_probe.check_route(np.asarray(route), radius=2.0)


@pytest.mark.parametrize(
    "argv, message",
    [
        (["/nonexistent", "1,2"], "not a run directory"),
        (["/nonexistent", "1,a"], "goal points must be numbers"),
        (["/nonexistent", "1,2", "--episodes", "0"], "--episodes must be >= 1"),
    ],
)
def test_actor_probe_refuses_bad_input(argv, message, capsys):
    from benchmarks import actor_probe

    assert actor_probe.main(argv) == 2
    first = capsys.readouterr().err.splitlines()[0]
    assert first.startswith("error: ") and message in first


@pytest.mark.parametrize(
    "probe, argv, message",
    [
        ("critic_probe", ["/nonexistent", "--episodes", "0"], "--episodes must be >= 1"),
        ("critic_probe", ["/nonexistent"], "not a run directory"),
        ("visit_map", ["/nonexistent"], "not a run directory"),
        ("reward_probe", ["/nonexistent", "--seed-index", "1"], "not a run directory"),
    ],
)
def test_run_probes_share_the_exit_2_contract(probe, argv, message, capsys):
    import importlib

    module = importlib.import_module(f"benchmarks.{probe}")
    assert module.main(argv) == 2
    first = capsys.readouterr().err.splitlines()[0]
    assert first.startswith("error: ") and message in first


def test_same_metrics_compares_all_but_time_keys(tmp_path, capsys):
    import gzip

    from benchmarks import same_metrics

    rows = [{"iteration": i, "env_steps": 10 * i, "a": i / 3, "time/x": i} for i in (1, 2, 3)]
    run = tmp_path / "run"
    run.mkdir()
    (run / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    # The reference: other wall-clock values, one row fewer, stored gzipped.
    ref_rows = [{**r, "time/x": 99} for r in rows[:2]]
    ref = tmp_path / "ref.jsonl.gz"
    with gzip.open(ref, "wt") as f:
        f.writelines(json.dumps(r) + "\n" for r in ref_rows)
    assert same_metrics.main([str(run), str(ref)]) == 0
    assert capsys.readouterr().out.strip() == "identical: 2 rows (iterations 1-2)"
    # A value and a missing key in iteration 2 are both named.
    other = tmp_path / "other.jsonl"
    changed = [ref_rows[0], {"iteration": 2, "env_steps": 20, "b": 1.0}]
    other.write_text("".join(json.dumps(r) + "\n" for r in changed))
    assert same_metrics.main([str(run), str(other)]) == 1
    assert capsys.readouterr().out.strip() == "differ: iteration 2 (2 keys: a, b)"
    assert same_metrics.main([str(run), str(tmp_path / "missing")]) == 2
    assert capsys.readouterr().err.startswith("error: no metrics file at ")
    later = tmp_path / "later.jsonl"
    later.write_text(json.dumps({"iteration": 9, "env_steps": 90}) + "\n")
    assert same_metrics.main([str(run), str(later)]) == 2
    assert capsys.readouterr().err.startswith("error: no iteration in common between ")


def test_learning_curve_window_table_by_hand():
    from benchmarks import learning_curve

    success, seconds = "train/success_rate", "time/iteration_s"
    rows = [
        {"env_steps": 100, success: 0.2, "sac/alpha": [0.1, 0.3], seconds: 5},
        {"env_steps": 200, success: 0.4, "curriculum/distance": 8.0, seconds: 7},
        {"env_steps": 300, success: 1.0, seconds: 9},
    ]
    lines = learning_curve.window_table(rows, 200).splitlines()
    assert len(lines) == 4  # head, rule, (0, 200], (200, 400]
    first = [c.strip() for c in lines[2].split("|")[1:-1]]
    # train success (0.2 + 0.4) / 2; curriculum/distance only where logged; alpha the mean
    # over seeds of its one row; median seconds of 5 and 7.
    assert first == ["0-200", "0.3", "", "", "8", "", "0.2", "", "6.0"]
    second = [c.strip() for c in lines[3].split("|")[1:-1]]
    assert second[1] == "1" and second[-1] == "9.0"


def test_learning_curve_command_prints_windows_and_refuses_a_negative_window(tmp_path, capsys):
    from benchmarks import learning_curve

    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(json.dumps({"env": "ant", "preset": "quick"}))
    rows = [
        {"env_steps": e, "time/elapsed_s": 60.0 * e / 1000, "time/iteration_s": 60.0,
         "eval/success": s, "eval/success/0": s, "eval/success/1": s, "train/success_rate": s}
        for e, s in ((1000, 0.0), (2000, 0.9), (3000, 0.5), (4000, 0.85))
    ]  # fmt: skip
    (run / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    argv = [str(run), "--out", str(tmp_path / "plots"), "--target", "0.8"]
    assert learning_curve.main([*argv, "--window", "-1"]) == 2
    assert capsys.readouterr().err.startswith("error: --window must be >= 0")
    assert learning_curve.main([*argv, "--window", "2000"]) == 0
    out = capsys.readouterr().out
    assert "first eval/success >= 0.8: 0.900 at 2,000 env steps, 2.0 min" in out
    assert "every evaluation >= 0.8 from 4,000 env steps" in out
    assert "| 0-2k | 0.45 |" in out and "| 2-4k | 0.675 |" in out
    assert (tmp_path / "plots" / "run_success.png").exists()
