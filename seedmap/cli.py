"""The ``seedmap`` command: one typer app, thin wrappers over the package's pipelines.

Every command that writes results writes into a fresh folder atomically (temporary name, then
rename) together with its resolved config. User errors print one line and exit with code 2.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import List, Optional

import typer

from seedmap import __version__
from seedmap.errors import SeedmapError

app = typer.Typer(
    name="seedmap",
    help="Semantic stereo SLAM and panicle 3D reconstruction with sorghum seeds as landmarks.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
simulate_app = typer.Typer(help="Render simulated datasets with ground truth.", no_args_is_help=True)
train_app = typer.Typer(help="Train the learned detector and segmenter.", no_args_is_help=True)
eval_app = typer.Typer(help="Evaluate results against ground truth.", no_args_is_help=True)
app.add_typer(simulate_app, name="simulate")
app.add_typer(train_app, name="train")
app.add_typer(eval_app, name="eval")

ConfigOpt = typer.Option(None, "--config", "-c", help="YAML config file (defaults otherwise).")
SetOpt = typer.Option(None, "--set", "-s", help="Override a config value: --set section.key=value (repeatable).")


def _version(value: bool) -> None:
    if value:
        typer.echo(f"seedmap {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="Print the version."),
) -> None:
    """seedmap: maps of crop plants from stereo cameras, with sorghum seeds as landmarks."""


# ================================================================================================
# simulate (seedmap.sim)
# ================================================================================================


# ================================================================================================
# detect / train / eval detect (seedmap.detect)
# ================================================================================================


# ================================================================================================
# slam / demo / eval associate / eval slam (seedmap.associate, seedmap.slam)
# ================================================================================================


# ================================================================================================
# benchmark (seedmap.eval)
# ================================================================================================


# ================================================================================================
# reconstruct / count / simulate panicle (seedmap.recon)
# ================================================================================================


# ================================================================================================
# bag-info / batch (seedmap.io, seedmap.viz)
# ================================================================================================


def main() -> None:
    """Console entry point: user errors become one line on stderr and exit code 2."""
    try:
        app()
    except SeedmapError as e:
        typer.secho(f"error: {e}", err=True, fg=typer.colors.RED)
        sys.exit(2)
    except KeyboardInterrupt:
        typer.secho("interrupted", err=True)
        sys.exit(130)


if __name__ == "__main__":
    main()
