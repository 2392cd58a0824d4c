"""The commands that read a run directory (README.md, "Pictures" and "Plots"):

    python -m d2c_jax.render RUN_DIR [--out RUN_DIR/policy.gif] [--still strip.png]
        [--html policy.html] [--checkpoint ITERATION]
    python -m d2c_jax.plots RUN_DIR
    python -m d2c_jax.plots compare RUN_DIR [RUN_DIR ...] [--out compare.png]

Both exit with status 0, or 2 with a one-line `error: ...` on stderr. Loading a run and
drawing its plots are `training.runs`'; the drawing itself is `viewing`'s.
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import jax
import numpy as np

import envs
from d2c_jax.core import networks, rollout, sac
from d2c_jax.training import logging as logging_lib
from d2c_jax.training.runs import RunError, check_seed_index, load_run, read_config, write_plots
from d2c_jax.viewing import html as viewer_html
from d2c_jax.viewing import plots, render


def trained_policy(cfg, env, ts, seed_index: int = 0):
    """The deterministic policy (tanh of the mean, as in evaluation) of one seed of ts."""
    sac_state = jax.tree.map(lambda x: x[seed_index], ts.sac)
    return sac.make_policy(networks.make_networks(cfg.sac, env), sac_state, env, deterministic=True)


def render_policy(
    run_dir,
    out=None,
    *,
    seed_index: int = 0,
    key: int = 0,
    width: int = 240,
    height: int = 240,
    fps: float = 20.0,
    still=None,
    html=None,
    checkpoint: int | None = None,
) -> pathlib.Path:
    """Renders a trained run's policy reaching each goal mode: one tile per mode, one video.

    With `still` (a .png path), also writes `still_strip` of the same episodes: one row per
    mode, five moments of its episode. With `html` (a .html path), also writes the same
    episodes in brax's interactive 3-D viewer (`viewing.html`), one viewer per mode.
    `checkpoint` is the iteration whose policy is drawn (default: the newest checkpoint).

    Returns the path of the video (default RUN_DIR/policy.gif).

    Raises:
      RunError(2): as `runs.load_run` (no config, no checkpoint at `checkpoint`), or a
        `seed_index` outside the run's seeds.
    """
    cfg, env, ts = load_run(run_dir, checkpoint)
    check_seed_index(seed_index, ts.iteration.shape[0], run_dir)
    policy = trained_policy(cfg, env, ts, seed_index)
    # One episode per mode from the episode loop (the modes as an argument, not constants).
    episodes = jax.jit(lambda goals, k: rollout.trajectories(env, policy, goals, k))
    trace = episodes(env.goal_points, jax.random.key(key))  # (n_modes, H + 1, ...)
    if html is not None:
        page = viewer_html.rollout_html(env, trace, titles=mode_titles(env, trace), fps=fps)
        viewer_html.save_html(page, html)
    frames = render.render_frames(env, trace, width=width, height=height)  # (n_modes, H+1, h, w, 3)
    if still is not None:
        render.save_image(render.still_strip(frames), still)
    out = pathlib.Path(run_dir) / "policy.gif" if out is None else out
    return render.save_video(render.tile(frames), out, fps=fps)


def mode_titles(env, trace) -> list[str]:
    """A heading per episode of a Trace with one episode per goal mode: the mode, its
    goal, and the first step that reaches it."""
    titles = []
    for k, (goal, success) in enumerate(zip(env.goal_points, trace.success, strict=True)):
        hits = np.flatnonzero(np.asarray(success))
        reached = f"reached at step {hits[0]}" if hits.size else "not reached"
        point = ", ".join(f"{float(x):.2f}" for x in np.asarray(goal))
        titles.append(f"mode {k}: goal ({point}), {reached}")
    return titles


def render_main(argv=None) -> int:
    """`python -m d2c_jax.render`: exit status 0, or 2 with a one-line error."""
    parser = argparse.ArgumentParser(description="Render a trained run's policy per goal mode.")
    parser.add_argument("run_dir", help="a run directory written by train.py")
    parser.add_argument("--out", default=None, help="video path (.gif or .mp4)")
    parser.add_argument(
        "--seed-index", type=int, default=0, help="which run: arm x N + (seed - S) of a sweep"
    )
    parser.add_argument("--size", type=int, default=240, help="tile width and height")
    parser.add_argument("--fps", type=float, default=20.0)
    parser.add_argument("--still", default=None, help="also a still strip (.png): 5 moments")
    parser.add_argument(
        "--html", default=None, help="also the episodes in an interactive 3-D viewer (.html)"
    )
    parser.add_argument(
        "--checkpoint", type=int, default=None, help="iteration to render (default: newest)"
    )
    args = parser.parse_args(argv)
    try:
        path = render_policy(
            args.run_dir,
            args.out,
            seed_index=args.seed_index,
            width=args.size,
            height=args.size,
            fps=args.fps,
            still=args.still,
            html=args.html,
            checkpoint=args.checkpoint,
        )
    # OSError: an --out, --still or --html path that cannot be written.
    except (RunError, RuntimeError, OSError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    for written in (args.html, args.still, path):
        if written is not None:
            print(f"wrote {written}")
    return 0


def plots_main(argv=None) -> int:
    """`python -m d2c_jax.plots RUN_DIR` redraws RUN_DIR/plots from its metrics;
    `python -m d2c_jax.plots compare RUN_DIR [RUN_DIR ...] [--out FILE] [--metric KEY]`
    draws one metric of several runs in one figure (default: eval/success into
    ./compare.png).

    A first argument `compare` is always the subcommand (a run directory of that name is
    redrawn as `./compare`). Returns 0, or 2 with a one-line `error: ...` on stderr.
    """
    argv = sys.argv[1:] if argv is None else list(argv)
    compare = argv[:1] == ["compare"]
    prog = "python -m d2c_jax.plots"
    if compare:
        parser = argparse.ArgumentParser(
            prog=f"{prog} compare",
            description="Draw the eval success (or another metric) of several runs in one "
            "figure: mean +- std over each directory's seeds, one curve per arm for a sweep.",
        )
        # nargs="*" and a check below: argparse's own "required" error is two lines.
        parser.add_argument("run_dirs", nargs="*", metavar="RUN_DIR", help="run directories")
        parser.add_argument("--out", default="compare.png", help="figure path (.png)")
        parser.add_argument(
            "--metric",
            default="eval/success",
            help="the metrics.jsonl key to draw, e.g. curriculum/distance (docs/METRICS.md)",
        )
        args = parser.parse_args(argv[1:])
        run_dirs = [pathlib.Path(d) for d in args.run_dirs]
    else:
        parser = argparse.ArgumentParser(
            prog=prog,
            description="Redraw a run's plots (RUN_DIR/plots) from its metrics.",
            epilog=f"Also: {prog} compare RUN_DIR [RUN_DIR ...] [--out FILE] [--metric KEY] "
            "draws several runs in one figure. A first argument 'compare' is always that "
            "subcommand; redraw a run directory named compare as ./compare.",
        )
        parser.add_argument("run_dir", help="a run directory written by train.py")
        run_dirs = [pathlib.Path(parser.parse_args(argv).run_dir)]
    try:
        if not run_dirs:
            raise RunError("compare: no run directories given", 2)
        cfgs = [read_config(run_dir) for run_dir in run_dirs]
        for run_dir in run_dirs:
            if not (run_dir / "metrics.jsonl").is_file():
                raise RunError(f"{run_dir} has no metrics.jsonl", 2)
        if compare:
            runs = [(d, logging_lib.read_metrics(d / "metrics.jsonl")) for d in run_dirs]
            sweeps = [getattr(c, "sweep", ()) for c in cfgs]
            plots.compare_runs(runs, args.out, sweeps, args.metric)
            written = args.out
        else:
            (run_dirs[0] / "plots").mkdir(exist_ok=True)
            write_plots(run_dirs[0], envs.make(cfgs[0].env))
            written = run_dirs[0] / "plots"
    # ValueError: unreadable metrics rows, or runs per row that do not fit the config;
    # OSError: a figure that cannot be written (e.g. --out in a missing directory).
    except (RunError, ValueError, OSError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(f"wrote {written}")
    return 0
