"""The typer app and its command groups, the options every command shares, and the entry point.

User errors (:class:`~seedmap.errors.SeedmapError`) print one line on stderr and exit with code 2.
"""

from __future__ import annotations

import sys

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
benchmark_app = typer.Typer(help="The paper's method comparison (Tables 1 and 2), reproducible.",
                            no_args_is_help=True)
config_app = typer.Typer(help="Show the configuration a command runs with.", no_args_is_help=True)
app.add_typer(simulate_app, name="simulate")
app.add_typer(train_app, name="train")
app.add_typer(eval_app, name="eval")
app.add_typer(benchmark_app, name="benchmark")
app.add_typer(config_app, name="config")

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


def main() -> None:
    """Console entry point: user errors become one line on stderr and exit code 2."""
    import logging

    log = logging.getLogger("seedmap")  # loader warnings (grey images converted, frames dropped): one line each
    for h in [h for h in log.handlers if getattr(h, "seedmap_cli", False)]:
        log.removeHandler(h)  # a previous main() in this process (tests): bind to the current sys.stderr
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("warning: %(message)s"))
    handler.seedmap_cli = True  # type: ignore[attr-defined]
    log.addHandler(handler)
    log.propagate = False
    try:
        app()
    except SeedmapError as e:
        typer.secho(f"error: {e}", err=True, fg=typer.colors.RED)
        sys.exit(2)
    except KeyboardInterrupt:
        typer.secho("interrupted", err=True)
        sys.exit(130)
