"""The TensorBoard and W&B sinks (issue 21 §3): what each writes, read back from its files.

One tiny two-seed run logs to both; its series are read back with tensorboardX's event
protos and W&B's offline record file, and compared with metrics.jsonl, which the loop
writes first. It is then resumed, after losing its last checkpoint (a hard kill), to a
longer total: it recomputes the lost iterations, which no series gets twice, and
continues the same series.
"""

import json
import pathlib
import shutil
import struct

import numpy as np
import pytest

from d2c_jax import config as config_lib
from d2c_jax import config_io
from d2c_jax.training import cli, loggers
from d2c_jax.training import logging as logging_lib


def needs_log_extra():
    """Skips the calling test, saying why, when the [log] extra is not installed."""
    pytest.importorskip("tensorboardX", reason="the [log] extra (tensorboardX) is not installed")
    pytest.importorskip("wandb", reason="the [log] extra (wandb) is not installed")


# 4 iterations of 400 env steps, evaluated at each, checkpointed at iterations 2 and 4.
TINY = ["--env", "medium_maze", "--preset", "tiny", "--seeds", "2", "--total-steps", "1600"]
TINY += ["--checkpoint-every", "800"]


# --- readers of the sinks' files ---------------------------------------------------------


def tfrecords(path: pathlib.Path):
    """The payloads of a TFRecord file (TensorBoard's event file format): each record is
    a little-endian u64 length, its masked CRC, the bytes and their masked CRC."""
    data = path.read_bytes()
    offset = 0
    while offset < len(data):
        (length,) = struct.unpack("<Q", data[offset : offset + 8])
        yield data[offset + 12 : offset + 12 + length]
        offset += 12 + length + 4


def tensorboard_events(series_dir: pathlib.Path):
    """(scalars {tag: [(step, value)]}, image tags {tag: [step]}) of a series directory."""
    from tensorboardX.proto import event_pb2

    scalars, images = {}, {}
    for path in sorted(series_dir.glob("events.out.tfevents.*")):
        for payload in tfrecords(path):
            event = event_pb2.Event.FromString(payload)
            for value in event.summary.value:
                if value.HasField("image"):
                    images.setdefault(value.tag, []).append(event.step)
                else:
                    scalars.setdefault(value.tag, []).append((event.step, value.simple_value))
    return scalars, images


def wandb_history(path: pathlib.Path) -> list[dict]:
    """The history rows of one W&B offline run file (.wandb): W&B's record log is a 7-byte
    header, then 32 KiB blocks of records, each with a 7-byte header (CRC u32, length
    u16, type u8: 1 full, 2 first, 3 middle, 4 last)."""
    from wandb.proto import wandb_internal_pb2

    rows = []
    data, offset, pending = path.read_bytes(), 7, b""
    while offset + 7 <= len(data):
        block_left = 32768 - offset % 32768
        if block_left < 7:
            offset += block_left
            continue
        length, kind = struct.unpack("<HB", data[offset + 4 : offset + 7])
        chunk = data[offset + 7 : offset + 7 + length]
        offset += 7 + length
        if kind == 0:
            continue
        pending = chunk if kind in (1, 2) else pending + chunk
        if kind in (1, 4):
            record = wandb_internal_pb2.Record.FromString(pending)
            if record.WhichOneof("record_type") == "history":
                items = record.history.item
                rows.append(
                    {(i.key or "/".join(i.nested_key)): json.loads(i.value_json) for i in items}
                )
    return rows


# --- the pieces ---------------------------------------------------------------------------


def test_series_names_one_per_run_in_run_order():
    cfg = config_lib.TrainConfig(seed=3, num_seeds=2)
    assert loggers.series_names(cfg) == ["seed3", "seed4"]
    swept = config_lib.TrainConfig(seed=0, num_seeds=2, sweep=(("sac.tau", (0.005, 0.01)),))
    assert loggers.series_names(swept) == [
        "tau=0.005-seed0",
        "tau=0.005-seed1",
        "tau=0.01-seed0",
        "tau=0.01-seed1",
    ]


def test_run_scalars_picks_each_runs_entry_and_drops_arrays():
    row = {"iteration": 3, "eval/success": [0.25, 0.5], "curriculum/goals": [[[1, 2]], [[3, 4]]]}
    assert loggers.run_scalars(row, 1, 2) == {"iteration": 3.0, "eval/success": 0.5}
    assert loggers.run_scalars({"a": 0.75, "g": [[1.0, 2.0]]}, 0, 1) == {"a": 0.75}


def test_missing_extra_names_the_pip_command(monkeypatch, capsys):
    needs_log_extra()
    monkeypatch.setitem(loggers._EXTRAS, "wandb", ("no_such_module_d2c", "pip install wandb"))
    assert loggers.missing_extra(("tensorboard",)) is None
    message = loggers.missing_extra(("tensorboard", "wandb"))
    assert "no_such_module_d2c" in message and "pip install wandb" in message
    assert cli.main([*TINY, "--log", "wandb", "--out", "/nonexistent/never"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("error: --log wandb needs") and "pip install" in err[0]


# --- a run logged to both sinks, then resumed after losing its last checkpoint -----------


@pytest.fixture(scope="module")
def logged_run(tmp_path_factory):
    """A finished tiny run with both sinks, its last checkpoint then deleted (as after
    SIGKILL) and the run resumed to 6 iterations: (run dir, its rows)."""
    needs_log_extra()
    out = tmp_path_factory.mktemp("logged") / "run"
    assert cli.main([*TINY, "--out", str(out), "--log", "tensorboard,wandb"]) == 0
    shutil.rmtree(out / "checkpoints" / "4")  # iterations 3 and 4 are redone
    argv = [*TINY, "--out", str(out), "--resume", "--log", "tensorboard", "--log", "wandb"]
    argv += ["--total-steps", "2400"]
    assert cli.main(argv) == 0
    return out, logging_lib.read_metrics(out / "metrics.jsonl")


def test_tensorboard_series_equal_metrics_once_per_step(logged_run):
    out, rows = logged_run
    steps = [400, 800, 1200, 1600, 2000, 2400]
    assert [r["env_steps"] for r in rows] == steps
    for run, name in enumerate(["seed0", "seed1"]):
        scalars, images = tensorboard_events(out / "tensorboard" / name)
        for key in ("eval/success", "sac/critic_loss", "curriculum/distance"):
            expected = [(r["env_steps"], r[key][run]) for r in rows]
            np.testing.assert_allclose(scalars[key], expected, rtol=1e-6)  # no step twice
        assert scalars["iteration"] == [(s, s // 400) for s in steps]
        assert "curriculum/goals" not in scalars
        assert images["plots/success"] == images["plots/curriculum"] == steps


def test_wandb_offline_runs_equal_metrics_once_per_step(logged_run):
    out, rows = logged_run
    progress = json.loads((out / "loggers.json").read_text())
    assert progress["wandb"]["last_step"] == progress["tensorboard"]["last_step"] == 2400
    ids = progress["wandb"]["ids"]
    assert len(set(ids)) == 2  # one W&B run per seed, reopened by the resumed run
    for run, run_id in enumerate(ids):
        files = sorted((out / "wandb").glob(f"offline-run-*-{run_id}/run-{run_id}.wandb"))
        assert len(files) == 2  # the first session and the resumed one
        history = [row for path in files for row in wandb_history(path)]
        assert [h["_step"] for h in history] == [r["env_steps"] for r in rows]
        assert [h["eval/success"] for h in history] == [r["eval/success"][run] for r in rows]
        assert [h["sac/critic_loss"] for h in history] == [r["sac/critic_loss"][run] for r in rows]
        # Images are flattened into their fields in the history (the file is in media/).
        assert all(h["plots/success/_type"] == "image-file" for h in history)


def test_config_of_a_run_starts_a_new_run_with_overrides(logged_run):
    out, _ = logged_run
    saved = config_io.from_dict(
        config_lib.TrainConfig, json.loads((out / "config.json").read_text())
    )
    cfg, run_dir, resume = cli.parse_args(["--config", str(out / "config.json"), "--seed", "5"])
    assert cfg == saved.__class__(**{**saved.__dict__, "seed": 5}) and not resume
    assert cli.parse_args(["--config", str(out), "--sac.tau", "0.02"])[0].sac.tau == 0.02
    assert cli.parse_args(["--config", str(out), "--env", "medium_maze"])[0] == saved


def test_bad_config_files_exit_2_with_one_line(logged_run, tmp_path, capsys):
    out, _ = logged_run
    values = json.loads((out / "config.json").read_text())
    bad = {
        "unknown field": {**values, "sac": {**values["sac"], "batchsize": 3}},
        "out of range": {**values, "sac": {**values["sac"], "batch_size": 0}},
        "section as value": {**values, "her": 0.5},
    }
    expected = ["unknown config fields: sac.batchsize", "--sac.batch-size must be", "her"]
    for (name, content), text in zip(bad.items(), expected, strict=True):
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps(content))
        assert cli.main(["--config", str(path), "--out", str(tmp_path / name)]) == 2, name
        err = capsys.readouterr().err.splitlines()
        assert err[0].startswith("error: ") and text in err[0], (name, err)
    (tmp_path / "broken.json").write_text("{")
    cases = [
        (["--config", str(tmp_path / "broken.json")], "not valid JSON"),
        (["--config", str(tmp_path / "none.json")], "no such file"),
        (["--config", str(out), "--env", "ant"], "--env ant conflicts"),
        (["--config", str(out), "--algo", "her"], "--algo her conflicts"),
    ]
    for argv, text in cases:
        assert cli.main([*argv, "--out", str(tmp_path / "x")]) == 2, argv
        err = capsys.readouterr().err.splitlines()
        assert err[0].startswith("error: ") and text in err[0], (argv, err)
    assert not (tmp_path / "x").exists()


# --- --help ---------------------------------------------------------------------------


def test_help_lists_every_flag_and_config_field_with_its_doc(capsys):
    from d2c_jax.training import validation

    assert cli.main(["--help"]) == 0
    text = capsys.readouterr().out
    flat = " ".join(text.split())
    for path in validation.field_ranges():
        if path.rsplit(".", 1)[-1] in cli.CLI_FIELDS and "." not in path:
            continue
        assert validation.flag_name(path) in text, path
    for flag in ("--env", "--config", "--preset", "--algo", "--seeds", "--log", "--resume"):
        assert flag in text
    doc = config_io.field_docs(config_lib.SACConfig)["batch_size"]
    assert f"{doc} (default: 512)" in flat
    assert "config: classifier" in text and "config: teachers" in text
    # Help does not weaken the exit-2 contract for bad input.
    assert cli.main(["--env", "nowhere"]) == 2
