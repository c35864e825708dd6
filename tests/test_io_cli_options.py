"""Loader options reach the commands: `--set dataset.*` opens a bag whose topics cannot be guessed."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from seedmap.cli import app

from helpers.bags import write_bag

TOPICS = ("/a/img", "/b/img")


def test_detect_and_slam_take_bag_topics_from_the_config(tmp_path):
    bag = write_bag(tmp_path / "odd.bag", "ros1", n=4, topics=TOPICS)
    runner = CliRunner()
    sets = ["--set", f"dataset.left_topic={TOPICS[0]}", "--set", f"dataset.right_topic={TOPICS[1]}"]

    res = runner.invoke(app, ["detect", str(bag), "--detector", "fast", "--out", str(tmp_path / "det"), *sets])
    assert res.exit_code == 0, res.output
    lines = (tmp_path / "det" / "detections.jsonl").read_text().splitlines()
    assert len(lines) == 8  # 4 frames x 2 cameras

    res = runner.invoke(app, ["slam", str(bag), "--detector", "fast", "--out", str(tmp_path / "slam"), "-q", *sets])
    assert res.exit_code == 0, res.output
    metrics = json.loads((tmp_path / "slam" / "metrics.json").read_text())
    assert metrics["frames"] == 4
    assert "dataset" in (tmp_path / "slam" / "config.yaml").read_text()


def test_unknown_loader_option_is_a_config_error(tmp_path):
    bag = write_bag(tmp_path / "odd.bag", "ros1", n=2, topics=TOPICS)
    res = CliRunner().invoke(app, ["slam", str(bag), "--out", str(tmp_path / "s"), "--set", "dataset.nonsense=1"])
    assert res.exit_code != 0
    assert not (tmp_path / "s").exists()
