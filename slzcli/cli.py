"""The `slz` command line: parse, call the library, print. The only place that prints or exits.

Exit codes scripts can trust: 0 done (a "no safe site" result included), 1 bad input,
config or a failure with a one-line reason naming the file or key, 2 usage.
"""

from __future__ import annotations

import functools
import json
import logging
import sys
from pathlib import Path
from typing import Any, Callable

import click

from slzcli import __version__
from slzcli.config import Config, dump, load_config
from slzcli.errors import SlzError

log = logging.getLogger("slzcli")


# ----------------------------------------------------------------------------- shared plumbing
def common_options(fn: Callable[..., Any]) -> Callable[..., Any]:
    """--config, --set, --json and -v on every command; the resolved Config is passed as ``config``."""

    @click.option("--config", "config_file", type=click.Path(dir_okay=False, path_type=Path),
                  help="YAML file layered over configs/default.yaml.")
    @click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE",
                  help="Override one key, e.g. --set mask.threshold=0.6 (repeatable).")
    @click.option("--json", "as_json", is_flag=True, help="Print the summary as one JSON object.")
    @click.option("-v", "--verbose", count=True, help="More log output (-vv for debug).")
    @functools.wraps(fn)
    def wrapper(config_file: Path | None, overrides: tuple[str, ...], as_json: bool, verbose: int,
                **kwargs: Any) -> None:
        _setup_logging(verbose)
        try:
            config = load_config(config_file, overrides)
            result = fn(config=config, **kwargs)
        except SlzError as err:
            _fail(str(err))
        except KeyboardInterrupt:
            click.echo("slz: interrupted", err=True)
            sys.exit(130)
        except Exception as err:  # a bug: still one line by default, the traceback with -vv
            if verbose >= 2:
                raise
            _fail(f"internal error ({type(err).__name__}: {err}); rerun with -vv for the traceback")
        if result is not None:
            summary, text = result
            click.echo(json.dumps(summary, indent=None, default=_json_default) if as_json else text)

    return wrapper


def _fail(message: str) -> None:
    click.echo(f"slz: error: {' '.join(message.split())}", err=True)
    sys.exit(1)


def _json_default(obj: Any) -> Any:
    if isinstance(obj, Path):
        return str(obj)
    if hasattr(obj, "tolist"):
        return obj.tolist()
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def _setup_logging(verbose: int) -> None:
    level = logging.WARNING if verbose == 0 else logging.INFO if verbose == 1 else logging.DEBUG
    logging.basicConfig(level=level, format="slz: %(levelname)s: %(message)s", stream=sys.stderr, force=True)
    logging.captureWarnings(True)


# ----------------------------------------------------------------------------- commands
@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="slz")
def main() -> None:
    """slz: safe landing zones from recorded RGB-D flights (ROS 1/2 bags, MCAP, TUM folders)."""


@main.group("config")
def config_group() -> None:
    """Inspect the configuration."""


@config_group.command("dump")
@common_options
def config_dump(config: Config) -> tuple[dict[str, Any], str]:
    """Print the resolved config (defaults + --config + --set), every key commented."""
    return config.to_dict(), dump(config).rstrip("\n")


# --- commands end (new commands go above this line) ---
