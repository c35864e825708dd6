"""``seedmap bag-info``: what a ROS bag holds (seedmap.io.rosbag)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from seedmap.cli.app import app


@app.command("bag-info")
def bag_info_cmd(
    bag: Path = typer.Argument(..., help="ROS1 .bag, ROS2 bag folder, .db3 or .mcap file."),
    sequence: bool = typer.Option(False, "--sequence", help="Also open it as a stereo sequence (topics, sync, calib)."),
    left_topic: Optional[str] = typer.Option(None, "--left-topic", help="Left image topic (else guessed)."),
    right_topic: Optional[str] = typer.Option(None, "--right-topic", help="Right image topic (else guessed)."),
    sync_tol: float = typer.Option(0.01, "--sync-tol", help="Stereo time-sync tolerance (s)."),
) -> None:
    """List a bag's topics, message types and counts (no ROS installation needed)."""
    from rich.console import Console
    from rich.table import Table

    from seedmap.io.rosbag import RosbagSequence, bag_info

    info = bag_info(bag)
    table = Table(title=f"{bag}  ({info.message_count} messages, {info.duration_s:.2f} s)")
    table.add_column("topic")
    table.add_column("type")
    table.add_column("count", justify="right")
    for t in info.topics:
        table.add_row(t.topic, t.msgtype, str(t.count))
    console = Console()
    console.print(table)
    if sequence:
        with RosbagSequence(bag, left_topic=left_topic, right_topic=right_topic, sync_tol_s=sync_tol) as seq:
            c = seq.calib
            console.print(f"stereo: {seq.left_topic} + {seq.right_topic}: {len(seq)} pairs, {seq.dropped} dropped; "
                          f"calib {c.width}x{c.height} fx={c.fx:.2f} baseline={c.baseline:.4f} m "
                          f"({'rectified' if seq.maps is None else 'rectified at load'})")
            # seq.warnings were reported on stderr as the loader found them (seedmap.io.common.LoaderWarnings)
