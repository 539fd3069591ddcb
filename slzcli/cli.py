"""The `slz` command line: parse, call the library, print. The only place that prints or exits.

Exit codes scripts can trust: 0 done (a "no safe site" result included), 1 bad input,
config or a failure with a one-line reason naming the file or key, 2 usage.
"""

from __future__ import annotations

import atexit
import dataclasses
import functools
import gc
import logging
import math
import sys
import threading
import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO, TypeVar

import click

from slzcli import render
from slzcli.api import load_config  # the Python API's: one way to a Config for both entry points
from slzcli.config import MAX_FLOAT_MAGNITUDE, Config, OutputLevel, dump, layer_sources
from slzcli.errors import SlzError
from slzcli.interrupt import sigterm_interrupts
from slzcli.methods import registry as method_registry
from slzcli.outputs.summary_json import envelope, summary_json
from slzcli.progress import DEFAULT_EVERY_S, Bar, BatchDisplay, RunsDisplay
from slzcli.records import BatchRow, RunSummary
from slzcli.version import __version__

if TYPE_CHECKING:
    from slzcli.synth.flight import PathKind

log = logging.getLogger("slzcli")

# What a command returns to ``common_options``: the ``--json`` object (printed through ``json_text``) and the
# text printed without ``--json``.
CommandResult = tuple[Mapping[str, object], str]
Command = Callable[..., CommandResult | None]  # a command body: the parsed options as keywords, ``config`` resolved
CallbackT = TypeVar("CallbackT", bound=Callable[..., object])  # a click callback, returned as it was


# ----------------------------------------------------------------------------- shared plumbing
LAYERS = "slz.config_layers"  # click context meta key: (profile, config file, --set items) as given


def _layers() -> tuple[str | None, Path | None, tuple[str, ...]]:
    layers: tuple[str | None, Path | None, tuple[str, ...]] = click.get_current_context().meta[LAYERS]
    return layers


def common_options(fn: Command) -> Callable[..., None]:
    """--profile, --config, --set, --json and -v on every command; the resolved Config is passed as ``config``.

    The layers as given are kept in the click context (``LAYERS``) for commands that resolve more
    than one config (``config dump``'s sources, ``compare --profiles``)."""

    @click.option("--profile", "profile", default=None, metavar="NAME",
                  help="Named profile layered between configs/default.yaml and --config (configs/profiles/NAME.yaml; "
                       "e.g. paper: the paper as published).")
    @click.option("--config", "config_file", type=click.Path(dir_okay=False, path_type=Path, readable=False),
                  help="YAML file layered over configs/default.yaml.")
    @click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE", callback=_check_overrides,
                  help="Override one key, e.g. --set mask.threshold=0.6 (repeatable).")
    @click.option("--json", "as_json", is_flag=True, help="Print the result as one JSON object on stdout (for "
                  "scripts; the text goes away).")
    @click.option("-v", "--verbose", count=True, help="More log output (-vv for debug).")
    @functools.wraps(fn)
    def wrapper(profile: str | None, config_file: Path | None, overrides: tuple[str, ...], as_json: bool,
                verbose: int, **kwargs: object) -> None:
        warned = _setup_logging(verbose)
        click.get_current_context().meta[LAYERS] = (profile, config_file, overrides)
        try:
            with sigterm_interrupts():
                config = load_config(config_file, overrides, profile)
                result = fn(config=config, **kwargs)
        except click.ClickException:  # a usage error found after parsing (exit 2): click prints it
            warned.flush()
            raise
        except SlzError as err:
            warned.flush()
            _fail(str(err), err if as_json else None)
        except KeyboardInterrupt:
            warned.flush()
            click.echo("slz: interrupted", err=True)
            from slzcli import interrupt

            if interrupt.abandoned():
                interrupt.exit_now(130)
            sys.exit(130)
        except Exception as err:  # a bug: still one line by default, the traceback with -vv
            warned.flush()
            if verbose >= 2:
                raise
            _fail(f"internal error ({type(err).__name__}: {err}); rerun with -vv for the traceback", err if as_json
                  else None)
        warned.flush()
        if result is not None:
            summary, text = result
            from slzcli.outputs.files import json_text  # strict JSON: NaN/inf become null
            from slzcli.outputs.summary_json import rounded

            click.echo(json_text(rounded(summary), indent=None) if as_json else text)

    return wrapper


def camera_option(fn: Callable[..., None]) -> Callable[..., None]:
    """``--camera NAME``: the camera preset (configs/camera/NAME.yaml, auto or none), as ``--set camera.preset=NAME``.

    Put it above ``@common_options``: it becomes the last override, so it wins over --set and --config.
    """
    from slzcli.config import CONFIG_DIR

    names = ["auto", "none", *sorted(p.stem for p in (CONFIG_DIR / "camera").glob("*.yaml"))]

    @click.option("--camera", "camera", type=click.Choice(names), default=None,
                  help="Camera preset: topic layout, intrinsics without CameraInfo, noise prior "
                       "(default: camera.preset, auto = guessed; slz info says which).")
    @functools.wraps(fn)
    def wrapper(camera: str | None, overrides: tuple[str, ...] = (), **kwargs: object) -> None:
        if camera is not None:
            overrides = (*overrides, f"camera.preset={camera}")
        return fn(overrides=overrides, **kwargs)

    return wrapper


# The longest line slz prints for one error or warning: messages bound the values they quote
# (errors.short_repr); this is the net under any that does not (a third-party error's text).
MAX_LINE_CHARS = 2000


def one_line(message: str, limit: int = MAX_LINE_CHARS) -> str:
    """Whitespace collapsed to single spaces, then cut in the middle when longer than ``limit``.

    The start names the file or key and the end usually holds the cause, so both are kept.
    """
    if len(message) > 4 * limit:  # split() of a many-megabyte text would copy it several times
        message = message[: 2 * limit] + " " + message[-2 * limit:]
    text = " ".join(message.split())
    if len(text) <= limit:
        return text
    head = (2 * limit) // 3
    return f"{text[:head]} [...] {text[-(limit - head - 7):]}"


def _fail(message: str, json_err: BaseException | None = None) -> None:
    """One line on stderr, exit 1; under ``--json`` (``json_err`` given) also the error object on stdout."""
    line = one_line(message)
    click.echo(f"slz: error: {line}", err=True)
    if json_err is not None:
        _echo_json_error(line, 1, json_err)
    sys.exit(1)


def _echo_json_error(message: str, exit_code: int, err: BaseException | None) -> None:
    from slzcli.outputs.files import json_text
    from slzcli.outputs.summary_json import error_object

    click.echo(json_text(error_object(message, exit_code, err), indent=None))


def _check_overrides(ctx: click.Context, param: click.Parameter, value: tuple[str, ...]) -> tuple[str, ...]:
    """``--set`` items that are not ``KEY=VALUE`` with a dotted key are usage errors (exit 2); whether the
    key exists and the value parses and fits is the config's to say (exit 1, naming the key)."""
    from slzcli.config import split_override

    for item in value:
        try:
            split_override(item)
        except SlzError as err:
            raise click.BadParameter(str(err)) from None
    return value


class _SlzGroup(click.Group):
    """The ``slz`` group: usage errors (exit 2) in slz's one error style, ``slz: error: ...`` after the
    usage line; under ``--json`` also the error object on stdout."""

    def main(self, args: Sequence[str] | None = None, prog_name: str | None = None, complete_var: str | None = None,
             standalone_mode: bool = True, **extra: Any) -> Any:  # click's own (overloaded on standalone_mode)
        argv = list(sys.argv[1:] if args is None else args)
        if not standalone_mode:
            return super().main(argv, prog_name, complete_var, standalone_mode, **extra)
        try:
            rv = super().main(argv, prog_name or "slz", complete_var, standalone_mode=False, **extra)
        except click.ClickException as err:
            _show_usage_error(err)
            if "--json" in argv:
                _echo_json_error(one_line(err.format_message()), err.exit_code, None)
            sys.exit(err.exit_code)
        except click.exceptions.Abort:
            click.echo("slz: interrupted", err=True)
            sys.exit(130)
        sys.exit(rv if isinstance(rv, int) else 0)


def _show_usage_error(err: click.ClickException) -> None:
    """click's usage error in slz's style: the usage and where help is, then ``slz: error: ...``."""
    ctx = getattr(err, "ctx", None)
    if ctx is not None:
        click.echo(ctx.get_usage(), err=True)
        click.echo(f"Try '{ctx.command_path} {ctx.help_option_names[0]}' for help.", err=True)
    click.echo(f"slz: error: {one_line(err.format_message())}", err=True)


class _WarningLines:
    """Python warnings (numpy's RuntimeWarning, ...) as one ``slz: WARNING:`` line per kind, repeats counted.

    The default display is two lines (file:line and the source line) and, through logging, one
    more per repeat elsewhere; here each (category, text) is shown once and the repeats are
    summed in one line at the end of the command (``flush``).
    """

    def __init__(self) -> None:
        self.seen: dict[tuple[str, str], int] = {}

    def __call__(self, message: Warning | str, category: type[Warning], filename: str, lineno: int,
                 file: TextIO | None = None, line: str | None = None) -> None:
        key = (category.__name__, " ".join(str(message).split()))
        self.seen[key] = self.seen.get(key, 0) + 1
        if self.seen[key] == 1:
            log.warning("%s: %s (at %s:%d; repeats are counted, not shown)", key[0], key[1], Path(filename).name,
                        lineno)

    def flush(self) -> None:
        repeats = {k: n - 1 for k, n in self.seen.items() if n > 1}
        if repeats:
            log.warning("%d repeat(s) of the warning(s) above were not shown (%s)", sum(repeats.values()),
                        "; ".join(f"{k[0]} x{n}" for k, n in repeats.items()))
        self.seen.clear()


class _OneLineRecords(logging.Filter):
    """Every log record on stderr is one bounded line (a warning quoting a recording's text included)."""

    def filter(self, record: logging.LogRecord) -> bool:
        text = record.getMessage()
        short = one_line(text)
        if short != text:
            record.msg, record.args = short, None
        return True


def _setup_logging(verbose: int) -> _WarningLines:
    level = logging.WARNING if verbose == 0 else logging.INFO if verbose == 1 else logging.DEBUG
    logging.basicConfig(level=level, format="slz: %(levelname)s: %(message)s", stream=sys.stderr, force=True)
    for log_handler in logging.getLogger().handlers:
        log_handler.addFilter(_OneLineRecords())
    handler = _WarningLines()
    warnings.showwarning = handler
    warnings.filterwarnings("always", category=RuntimeWarning)  # numpy: each occurrence reaches the handler
    return handler


# ----------------------------------------------------------------------------- the time window
WindowBound = tuple[str, float]  # ("offset" | "stamp", seconds)


def _time_bound(ctx: click.Context, param: click.Parameter, value: str | None) -> WindowBound | None:
    """``--start/--end``: seconds after the first frame (``12.5``), or a stamp on the recording's clock
    (``@1712345678.25``, seconds; the ``@`` as in ``date -d @SECONDS``)."""
    if value is None:
        return None
    kind, text = ("stamp", value[1:]) if value.startswith("@") else ("offset", value)
    try:
        seconds = float(text)
    except ValueError:
        raise click.BadParameter(f"expected seconds (e.g. 12.5) or @STAMP (e.g. @1712345678.25), got {value!r}") \
            from None
    if not math.isfinite(seconds) or not 0 <= seconds <= MAX_FLOAT_MAGNITUDE:
        raise click.BadParameter(f"must be a number of seconds from 0 to {MAX_FLOAT_MAGNITUDE:g}, got {value!r}")
    return kind, seconds


def window_options(fn: CallbackT) -> CallbackT:
    """--start, --end, --stride, --max-frames: the part of a recording read (config sources.window)."""
    for option in reversed([
        click.option("--start", "win_start", callback=_time_bound, metavar="S|@STAMP",
                     help="Read from this many seconds after the first frame, or from stamp @STAMP (s, the "
                          "recording's clock). Sets sources.window.start_s / start_stamp_s."),
        click.option("--end", "win_end", callback=_time_bound, metavar="S|@STAMP",
                     help="Stop before this many seconds after the first frame, or before stamp @STAMP."),
        click.option("--stride", type=click.IntRange(1), default=None, metavar="N",
                     help="Read every Nth colour/depth pair in the window (sources.window.stride)."),
        click.option("--max-frames", type=click.IntRange(1), default=None, metavar="N",
                     help="Stop after N frames read (sources.window.max_frames)."),
    ]):
        fn = option(fn)
    return fn


def _seconds(bound: WindowBound, kind: str) -> float | None:
    """The bound's seconds when it is of ``kind`` ("offset" or "stamp"), else None."""
    return bound[1] if bound[0] == kind else None


def _windowed(config: Config, start: WindowBound | None, end: WindowBound | None, stride: int | None,
              max_frames: int | None) -> Config:
    """``config`` with the window options in sources.window (so they are in run.json and the rerun key)."""
    given = w = config.sources.window
    if start is not None:
        w = dataclasses.replace(w, start_s=_seconds(start, "offset"), start_stamp_s=_seconds(start, "stamp"))
    if end is not None:
        w = dataclasses.replace(w, end_s=_seconds(end, "offset"), end_stamp_s=_seconds(end, "stamp"))
    if stride is not None:
        w = dataclasses.replace(w, stride=stride)
    if max_frames is not None:
        w = dataclasses.replace(w, max_frames=max_frames)
    if w is given:
        return config
    if start is not None and end is not None and start[0] == end[0] and end[1] <= start[1]:
        raise click.BadParameter(f"--end must be later than --start ({end[1]:g} <= {start[1]:g} s)",
                                 param_hint="'--end'")
    from slzcli.sources.window import check_window

    check_window(w)
    return dataclasses.replace(config, sources=dataclasses.replace(config.sources, window=w))


# ----------------------------------------------------------------------------- commands
@click.group(cls=_SlzGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="slz")
def main() -> None:
    """slz finds safe landing zones in recorded RGB-D flights (ROS 1/2 bags, MCAP, TUM folders).

    \b
    Start with:
      slz info flight.bag                 what slz reads from the recording
      slz detect flight.bag -o runs/f1    the landing site; open runs/f1/report.html
    Every command has -h with an example.
    """
    _keep_heap_warm()
    _exit_without_collecting()


# glibc mallopt parameters (malloc.h): keep 64 MiB of freed heap for the next frame's arrays; serve blocks up to
# 32 MiB (glibc's own ceiling for its dynamic threshold, DEFAULT_MMAP_THRESHOLD_MAX) from the heap.
_M_TOP_PAD, _M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -2, -1, -3
_HEAP_PAD_BYTES, _MMAP_THRESHOLD_BYTES = 64 << 20, 32 << 20


def _keep_heap_warm() -> None:
    """Stop glibc handing each frame's ~20 MB of temporaries back to the OS and faulting them in again.

    Measured (benchmarks/terrain.py): the four maps take 23.8 ms in a fresh process with the
    default allocator (~4,900 page faults per frame) and 17.0 ms with the heap kept. Setting the trim threshold
    also stops glibc raising its mmap threshold as large blocks are freed, so that is set too: left at 128 KiB,
    every image, message and map (all larger) is mmapped and faulted in afresh (the info pass over a 300-frame
    848 KB-a-frame recording: 308,000 page faults and 1.2 s, against 5,500 and 0.54 s). A process setting, so it
    belongs to the program's entry point, not to the library. No-op off glibc.
    """
    import ctypes
    import ctypes.util

    name = ctypes.util.find_library("c")
    if not name or not sys.platform.startswith("linux"):
        return
    try:
        libc = ctypes.CDLL(name)
        libc.mallopt(_M_TOP_PAD, _HEAP_PAD_BYTES)
        libc.mallopt(_M_TRIM_THRESHOLD, 2 * _HEAP_PAD_BYTES)
        libc.mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD_BYTES)
    except (OSError, AttributeError):
        return


@functools.cache
def _exit_without_collecting() -> None:
    """Freeze the garbage collector's objects at the interpreter's exit, after every other exit handler.

    The interpreter's finalisation runs full collections over every object the imports left (numba's, scipy's:
    hundreds of thousands), which took 0.2-0.3 s of a detect process after its last file was written; frozen
    objects are not traversed, and each is still freed as its module is cleared. Only a cycle of objects
    is no longer finalised at exit, and by then every file slz writes is closed. A process setting, registered
    once: an exit handler does nothing to a library caller's process before it exits.
    """
    atexit.register(gc.freeze)   # runs after the handlers a run registers later (the last registered runs first)


@main.group("config")
def config_group() -> None:
    """Show the configuration slz would use."""


@config_group.command("dump", short_help="Print the resolved config with each key's source.")
@common_options
def config_dump(config: Config) -> CommandResult:
    """Print the resolved config (defaults + --profile + --config + --set), each key with its source.

    With --json: the config as one JSON object (no comments).

    \b
    Example:
      slz config dump --set camera.mount=pitch_down_30
    """
    from slzcli.outputs.summary_json import Exact

    profile, config_file, overrides = _layers()
    # --json unrounded: values must round-trip
    return Exact(config.to_dict()), dump(config, layer_sources(profile, config_file, overrides)).rstrip("\n")


@main.command("info", short_help="Show what slz reads from a recording.")
@click.argument("bag", type=click.Path(path_type=Path, readable=False))
@window_options
@camera_option
@common_options
def info_cmd(config: Config, bag: Path, win_start: WindowBound | None, win_end: WindowBound | None,
             stride: int | None, max_frames: int | None) -> CommandResult:
    """Show what slz reads from BAG: topics, rates, the streams it would use and why, intrinsics, frames.

    Pairable frames are counted within --start/--end/--stride/--max-frames when given.

    \b
    Example:
      slz info flight.bag --camera d435
    """
    from slzcli import gravity
    from slzcli.sources import open_recording
    from slzcli.sources.depth_check import check_depth
    from slzcli.sources.info_text import info_text

    config = _windowed(config, win_start, win_end, stride, max_frames)
    with open_recording(bag, config) as rec:
        info = gravity.apply(bag, rec, rec.info(), config)[1]
    depth = check_depth(bag, config, info)  # a few frames decoded: the depth's range, a wrong unit warned of
    if depth is not None and depth.warning:
        log.warning("%s: %s", bag, depth.warning)
    return {**info.to_dict(), "depth": None if depth is None else depth.to_dict()}, info_text(info, depth)


@main.group("vocab")
def vocab_group() -> None:
    """Build ORB vocabularies for ORB-SLAM3."""


@vocab_group.command("build", short_help="Train an ORB vocabulary from recordings.")
@click.argument("recordings", nargs=-1, required=True, type=click.Path(path_type=Path, readable=False))
@click.option("-o", "--output", "output", required=True,
              type=click.Path(dir_okay=False, path_type=Path, readable=False),
              help="Vocabulary file to write (DBoW2 text format).")
@click.option("--force", is_flag=True, help="Replace an existing vocabulary file (never any other file).")
@common_options
def vocab_build(config: Config, recordings: tuple[Path, ...], output: Path, force: bool) -> CommandResult:
    """Train a DBoW2 ORB vocabulary from RECORDINGS (slam.vocab.* sets k, levels, frames).

    \b
    Example:
      slz vocab build flight1.bag flight2.bag -o my_vocab.txt
    """
    from slzcli.slam.vocabulary import build_from_recordings

    r = build_from_recordings(list(recordings), output, config, force=force)
    summary = {"path": r.path, "recordings": r.recordings, "frames": r.frames, "descriptors": r.descriptors,
               "nodes": r.nodes, "words": r.words, "size_bytes": r.size_bytes, "seconds": round(r.seconds, 3)}
    text = (f"{r.path}: {r.words} words ({r.nodes} nodes, k={config.slam.vocab.k}, L={config.slam.vocab.levels}) "
            f"from {r.descriptors} descriptors in {r.frames} frames of {r.recordings} recording(s); "
            f"{r.size_bytes / 1024:.0f} KiB in {r.seconds:.1f} s")
    return summary, text


def _start_floats(ctx: click.Context, param: click.Parameter, value: str | None) -> tuple[float, ...] | None:
    if value is None:
        return None
    others = [f"--{k}" for k in ("scenario", "start", "offset") if k != param.name and ctx.params.get(k) is not None]
    if others:
        raise click.BadParameter(f"give one start: --{param.name} or {others[0]}, not both")
    try:
        values = tuple(float(v) for v in value.split(","))
    except ValueError:
        raise click.BadParameter(f"expected comma-separated numbers, got {value!r}") from None
    if not all(math.isfinite(v) and abs(v) <= MAX_FLOAT_MAGNITUDE for v in values):
        raise click.BadParameter(f"every value must be a finite number within +-{MAX_FLOAT_MAGNITUDE:g}, got {value!r}")
    if len(values) not in (3, 4):
        raise click.BadParameter(f"expected X,Y,Z or X,Y,Z,YAW, got {len(values)} value(s)")
    return values


class FiniteFloatRange(click.FloatRange):
    """click's FloatRange lets NaN through (every comparison with NaN is false); this one does not.

    Its range in --help leaves out a bound only there for the platform (``x>0``, not ``0<x<=9223372036.0``)."""

    def _describe_range(self) -> str:
        if self.max is not None and self.max >= threading.TIMEOUT_MAX:
            return f"x{'>' if self.min_open else '>='}{self.min:g}"
        return super()._describe_range()

    def convert(self, value: float, param: click.Parameter | None, ctx: click.Context | None) -> float:
        rv: float = super().convert(value, param, ctx)
        if not math.isfinite(rv):
            self.fail(f"{rv} is not a finite number", param, ctx)
        return rv


@main.group("land")
def land_group() -> None:
    """Simulate the landing on a site slz detect chose."""


@land_group.command("simulate", short_help="Simulate the IBVS descent onto a run's site.")
@click.argument("run", type=click.Path(path_type=Path, readable=False))
@click.option("-o", "--output", "output", type=click.Path(file_okay=False, path_type=Path, readable=False),
              help="Output folder (default: RUN/ibvs).")
@click.option("--scenario", type=click.IntRange(1, 4), help="Paper start (world frame): 1 (0,0,10), "
              "2 (-3,12,9), 3 (0,0,7), 4 (0,0,10) m.")
@click.option("--start", callback=_start_floats, metavar="X,Y,Z[,YAW]",
              help="Start position in the run's world frame (m, ENU as in slz synth --start; yaw deg from +x, "
              "counter-clockwise).")
@click.option("--offset", callback=_start_floats, metavar="X,Y,Z[,YAW]",
              help="Start as an offset from the site centre (m, world x/y/up; yaw deg). "
              "Default: control.sim.start_offset_m (the paper's scenario 1 geometry).")
@click.option("--runs", type=click.IntRange(1), default=1, show_default=True,
              help="Monte Carlo runs over start scatter, pose noise and gusts.")
@click.option("--seed", type=click.IntRange(0), default=None, help="Seed of the noise (and of the start scatter); "
              "default control.noise.seed.")
@common_options
def land_simulate(config: Config, run: Path, output: Path | None, scenario: int | None,
                  start: tuple[float, ...] | None, offset: tuple[float, ...] | None, runs: int,
                  seed: int | None) -> CommandResult:
    """Simulate the image-moment IBVS descent onto the site of RUN/landing.json (docs/METHOD.md 2.6-2.9).

    \b
    Example:
      slz land simulate runs/f1 --offset 2,-1.5,8 --runs 100
    """
    from slzcli.control import montecarlo
    from slzcli.control.simulate import check_target, resolve_start, simulate
    from slzcli.outputs import ibvs as ibvs_out
    from slzcli.outputs import ibvs_plots

    if sum(v is not None for v in (scenario, start, offset)) > 1:  # whatever order they came in
        from slzcli.errors import ConfigError
        raise ConfigError("--start", "give one of --scenario, --start or --offset, not both")
    from slzcli import bounds

    bounds.check(bounds.simulation_sizes(config, runs))
    target = ibvs_out.read_target(run, config.uav.footprint_m)
    target = check_target(ibvs_out.landing_path(run), target, config.uav.footprint_m,
                          config.control.sim.target_tolerance)
    out = output or ibvs_out.landing_path(run).parent / "ibvs"
    start_world = resolve_start(target, config, scenario, start, offset)
    mc_seed = config.control.noise.seed if seed is None else seed
    with ibvs_out.output_folder(out, ibvs_out.landing_path(run), runs) as tmp:
        if runs == 1:
            result = simulate(target, start_world[None], config, log=True, seed=seed)
            metrics = result.metrics(0)
            ibvs_out.write_single(tmp, result, metrics, target, config.camera)
        else:
            with ibvs_out.montecarlo_rows(tmp) as add_rows, \
                    RunsDisplay(runs, config.control.montecarlo.chunk_runs, config.output.progress_every_s) as tick:
                mc = montecarlo.run_chunked(target, start_world, runs, mc_seed, config, on_chunk=add_rows,
                                            progress=tick)
            mc_summary = {**montecarlo.summarise(mc), "seed": mc_seed, "start_world": start_world.tolist()}
            ibvs_out.write_montecarlo(tmp, mc, mc_summary, rows_written=True)
            ibvs_plots.montecarlo_histograms(tmp / "montecarlo_hist.png", mc)
        names = sorted(p.name for p in tmp.iterdir() if not p.name.startswith("."))
    if runs == 1:
        return {**metrics, "output": str(out), "files": names}, render.simulate_text(metrics, out)
    return {**mc_summary, "output": str(out), "files": names}, f"{montecarlo.table(mc_summary)}\n-> {out}"


@main.command("synth", short_help="Render a ground-truthed synthetic flight.")
@click.argument("scene", required=False)
@click.option("-o", "--output", "output", type=click.Path(path_type=Path, readable=False),
              help="Recording to write (default: SCENE[_VARIANTS]_s{seed}.mcap/.bag or a bag folder, here).")
@click.option("--list", "list_scenes", is_flag=True, help="List the scenes and their variants, then exit.")
@click.option("--frames", type=click.IntRange(1), help="Number of frames (default synth.frames).")
@click.option("--scenario", type=click.IntRange(1, 4), help="Paper start position (world ENU): 1 (0,0,10), "
              "2 (-3,12,9), 3 (0,0,7), 4 (0,0,10) m. Default: the scene's own (playground 3, office 4, else 1).")
@click.option("--start", callback=_start_floats, metavar="X,Y,Z",
              help="Start position (m, world ENU) instead of --scenario.")
@click.option("--seed", type=click.IntRange(0), help="Seed of the flight wobble and sensor noise (default synth.seed).")
@click.option("--format", "fmt", default="mcap", show_default=True,
              type=click.Choice(["mcap", "ros1", "ros2-sqlite", "ros2-mcap", "mcap-ros1"]),
              help="mcap = ROS 2 MCAP file; ros1 = .bag; ros2-* = rosbag2 folder.")
@click.option("--depth-encoding", default="16UC1", show_default=True,
              type=click.Choice(["16UC1", "32FC1", "mono16", "compressedDepth", "compressedDepth-32FC1"]))
@click.option("--color-encoding", default="rgb8", show_default=True,
              type=click.Choice(["rgb8", "bgr8", "jpeg", "png"]), help="Raw Image or CompressedImage (jpeg, png).")
@click.option("--rate", "rate_hz", type=FiniteFloatRange(1, 200), help="Frame rate in Hz (default synth.rate_hz).")
@click.option("--path", "path_kind", type=click.Choice(["hover", "descent", "transect"]),
              help="Camera path (default synth.path).")
@click.option("--variant", "variants", multiple=True, help="Scene variant (repeatable), e.g. sand, low_light; "
              "or SCENE:sand+low_light.")
@click.option("--contact-sheet", "sheet", type=click.Path(dir_okay=False, path_type=Path, readable=False),
              help="Where to write the preview PNG (default OUT.preview.png).")
@click.option("--force", is_flag=True, help="Replace an existing recording (a file, or a rosbag2 folder holding only "
              "the bag) and its ground truth.")
@common_options
def synth_cmd(config: Config, scene: str | None, output: Path | None, list_scenes: bool, frames: int | None,
              scenario: int | None, start: tuple[float, ...] | None, seed: int | None, fmt: str,
              depth_encoding: str, color_encoding: str, rate_hz: float | None, path_kind: PathKind | None,
              variants: tuple[str, ...], sheet: Path | None, force: bool) -> CommandResult:
    """Render a ground-truthed RGB-D recording of SCENE (datasets/scenes) with a .gt.npz sidecar.

    \b
    Example:
      slz synth parking_lot -o parking_lot.mcap --frames 20 --path descent
    """
    from slzcli.synth import record
    from slzcli.synth.scenes import list_scenes as scene_list
    from slzcli.synth.scenes import split_spec

    if list_scenes:
        rows = scene_list()
        text = "\n".join(f"{name:<12} {desc}\n{'':<12} variants: {', '.join(var)}" for name, desc, var in rows)
        return {"scenes": [{"name": n, "description": d, "variants": list(v)} for n, d, v in rows]}, text
    if scene is None:
        raise click.UsageError("give a SCENE (see slz synth --list)")
    if start is not None and len(start) != 3:
        raise click.UsageError("--start needs X,Y,Z")
    start_m = tuple(start) if start is not None else (
        record.scenario_start(config.synth.scenarios, scenario) if scenario is not None else None)
    s = config.synth
    options = record.SynthOptions(scene=scene, frames=frames or s.frames, rate_hz=rate_hz or s.rate_hz,
                                  path=path_kind or s.path, seed=s.seed if seed is None else seed,
                                  start_m=start_m, variants=variants, fmt=fmt,  # type: ignore[arg-type]
                                  color_encoding=color_encoding, depth_encoding=depth_encoding)
    if output is None:
        name, spec_variants = split_spec(scene)
        stem = "_".join([Path(name).stem, *spec_variants, *variants, f"s{options.seed}"])
        output = Path(stem + record.SUFFIX_OF_FORMAT.get(fmt, ""))
    with Bar(f"synth {scene}", "frames", config.output.progress_every_s) as bar:
        summary = record.synthesize(output, options, config, preview=sheet, progress=bar.tick, force=force)
    text = render.synth_text(summary, fmt, color_encoding, depth_encoding)
    return summary, text


def timeout_option(help_text: str) -> Callable[[CallbackT], CallbackT]:
    """``--timeout SECONDS``: a bound on each stage of a run (slzcli/timeout.py)."""
    # The largest wait both SIGALRM's setitimer and threading.Timer accept (about 292 years).
    return click.option("--timeout", "timeout_s", type=FiniteFloatRange(0, threading.TIMEOUT_MAX, min_open=True),
                        default=None, metavar="SECONDS", help=help_text)


@main.command("detect", short_help="Find the landing site in recordings.")
@click.argument("recordings", nargs=-1, required=True, type=click.Path(path_type=Path, readable=False))
@click.option("-o", "--output", "output", type=click.Path(file_okay=False, path_type=Path, readable=False),
              help="One recording: its run folder (default runs/<name>). Several, or a quoted glob pattern: "
                   "the folder for one run folder each plus summary.json and summary.csv (default runs/).")
@click.option("--method", type=click.Choice(method_registry.names()), default=None,
              help="Detection method (default: scoring.method): "
                   + "; ".join(f"{n}, {e.summary}" for n, e in method_registry.METHODS.items()) + ".")
@click.option("--force", is_flag=True, help="Replace finished runs (only the files slz writes in a run folder): "
              "redo one done for the same config and inputs, or replace one of another config.")
@click.option("--workers", type=click.IntRange(1), default=None,
              help="Local worker processes, one recording each (default: the number of cores).")
@click.option("--scheduler", metavar="ADDRESS", default=None,
              help="Run on this Dask distributed scheduler (e.g. tcp://host:8786) instead of local processes; "
                   "needs slz[dask] and the recordings at the same paths on the workers.")
@click.option("--outputs", type=click.Choice(["summary", "maps", "all"]), default=None,
              help="What each detection frame writes to frames/NNNNNN/ (default: output.level, maps): summary = "
                   "none, maps = maps.npz + overlay.png, all = + the heat-map PNGs of every map, score and mask.")
@timeout_option("Stop a recording when one stage (opening it, reading, SLAM, detection or writing of one "
                "frame, the final write) runs longer than this; it fails naming the stage, leaves no run folder, "
                "and a batch goes on. Default: no limit.")
@window_options
@camera_option
@common_options
def detect_cmd(config: Config, recordings: tuple[Path, ...], output: Path | None, method: str | None,
               force: bool, workers: int | None, scheduler: str | None, outputs: OutputLevel | None,
               timeout_s: float | None, win_start: WindowBound | None, win_end: WindowBound | None,
               stride: int | None, max_frames: int | None) -> CommandResult:
    """Find the landing site in each recording: terrain maps, fuzzy score, safety mask, SLAM points, site.

    RECORDINGS are paths or quoted glob patterns; each gets a run folder with report.html.

    \b
    Examples:
      slz detect flight.bag -o runs/f1
      slz detect 'flights/*.bag' -o runs/ --workers 2
    """
    from slzcli import batch
    from slzcli.outputs.records_json import to_json_object
    from slzcli.pipeline import RunOptions

    config = _windowed(config, win_start, win_end, stride, max_frames)
    if outputs is not None:  # a config value: it is in run.json's config and the rerun key
        config = dataclasses.replace(config, output=dataclasses.replace(config.output, level=outputs))

    paths = batch.expand(recordings)
    is_batch = len(recordings) > 1 or any(batch.is_pattern(r) for r in recordings)
    tasks = batch.plan(paths, output, batch=is_batch)
    batch_dir = output or Path("runs")
    summary_dir = batch_dir if is_batch else None
    with BatchDisplay(is_batch, config.output.progress_every_s) as show:
        result = batch.run_batch(tasks, config, workers=workers or batch.default_workers(), scheduler=scheduler,
                                 options=RunOptions(force, method, timeout_s), summary_dir=summary_dir,
                                 on_progress=show)
    rows = result.rows
    for r in rows:
        _warn_slam_maps(r.summary)
        _warn_untracked(r.summary)
    # --json names paths as the user gave them (the run folders and summary files keep absolute ones)
    given = {str(p.absolute()): str(p) for p in paths}
    given_run = {str(t.run_dir): str(output) if output is not None and not is_batch else str(batch_dir / t.run_dir.name)
                 for t in tasks}
    if not is_batch:
        row = rows[0]
        summary = row.summary
        if summary is None:
            raise _given_paths(SlzError(row.error or row.status), row.error_detail, {**given, **given_run})
        out = {"run": given_run.get(row.run, row.run), **summary_json(summary),
               "source": given.get(summary.source, summary.source)}
        t = summary.timings_ms
        if summary.method in t:  # "score" as in slz compare; the method's own key stays for older scripts
            out["timings_ms"] = {**t, "score": t[summary.method]}
        return envelope("detect", out), render.detect_text(Path(row.run), summary)
    failed = [r for r in rows if r.status == "failed"]
    if failed:
        raise SlzError(f"{len(failed)} of {len(rows)} recordings failed (first: {failed[0].error}); "
                       f"status of each in {batch_dir / 'summary.csv'}")
    totals = {**to_json_object(result.totals()), "summary_files": [str(p) for p in result.summary_files]}
    runs = [_batch_row(r, given, given_run) for r in rows]
    return envelope("batch", {"batch": totals, "runs": runs}), render.batch_text(totals, rows)


def _given_paths(err: SlzError, detail: Mapping[str, str] | None, given: dict[str, str]) -> SlzError:
    """A run's error with the absolute paths the workers used named as the user gave them."""
    text, detail = str(err), dict(detail or {})
    for absolute, as_given in sorted(given.items(), key=lambda kv: -len(kv[0])):
        text = text.replace(absolute, as_given)
        if detail.get("file") == absolute:
            detail["file"] = as_given
    out = SlzError(text)
    out.detail = detail  # type: ignore[attr-defined]  # read by outputs/summary_json.error_object
    return out


def _batch_row(r: BatchRow, given: dict[str, str], given_run: dict[str, str]) -> dict[str, object]:
    """A batch row of ``--json``: the paths as given, ``source`` as in detect and compare, the run's
    no-site reason and ground-truth figures when it has them."""
    from slzcli.outputs.batch_summary import row_json

    row = row_json(r)
    source = given.get(r.recording, r.recording)
    row.update(recording=source, source=source, run=given_run.get(r.run, r.run))
    row["reason"] = None if r.summary is None else r.summary.reason
    if r.summary is not None and r.summary.ground_truth is not None:
        row["ground_truth"] = r.summary.ground_truth
    return row


def _warn_slam_maps(s: RunSummary | None) -> None:
    """One warning line when SLAM started several maps: a run's results are in one map's frame."""
    if s is None or s.slam is None or s.slam.maps <= 1:
        return
    slam = s.slam
    seg = next(g for g in slam.segments if g.segment == slam.segment)
    what = "the site, trajectory.tum and points.ply are" if s.status == "site" else "trajectory.tum is"
    log.warning("%s: SLAM lost tracking and started %d maps, each in its own frame; %s in map %d (frames %d-%d, "
                "%d tracked); run.json summary.slam lists them all", s.source, slam.maps, what,
                slam.segment, seg.first_frame, seg.last_frame, seg.frames_tracked)


def _warn_untracked(s: RunSummary | None) -> None:
    """One warning line when SLAM left more than slam.max_untracked_share of the frames without a pose."""
    if s is not None and s.slam is not None and s.slam.untracked.warning:
        log.warning("%s: %s", s.source, s.slam.untracked.warning)


@main.command("compare", short_help="Compare fusion methods or profiles on the same frames.")
@click.argument("recordings", nargs=-1, required=True, type=click.Path(path_type=Path, readable=False))
@click.option("--methods", default=None, metavar="A,B", help="Methods to compare (default: compare.methods, "
              "fuzzy,bayes). With --profiles: the one method every profile uses (default: each profile's).")
@click.option("--profiles", default=None, metavar="A,B", help="Compare profiles instead of methods, e.g. "
              "paper,default: each a whole config (SLAM, maps, fusion) over the same frames, "
              "layered under --config and --set.")
@click.option("-o", "--output", "output", type=click.Path(file_okay=False, path_type=Path, readable=False),
              help="Output folder (default runs/compare_<first recording>).")
@click.option("--variants", is_flag=True, help="Also re-render each synth recording's scene in the variants of "
              "compare.variants (ground material, light) and compare on each.")
@click.option("--force", is_flag=True, help="Replace an existing slz compare folder (only the files it wrote).")
@timeout_option("Stop when one stage (opening a recording, reading, SLAM or detection of one frame, the final "
                "write) runs longer than this; the comparison fails naming the stage and leaves no output folder. "
                "Default: no limit.")
@window_options
@camera_option
@common_options
def compare_cmd(config: Config, recordings: tuple[Path, ...], methods: str | None, profiles: str | None,
                output: Path | None, variants: bool, force: bool, timeout_s: float | None,
                win_start: WindowBound | None, win_end: WindowBound | None, stride: int | None,
                max_frames: int | None) -> CommandResult:
    """Compare fusion methods (fuzzy, Bayes, px4slp) on the same frames and SLAM points.

    Time, agreement and, for slz synth recordings, accuracy against ground truth. With --profiles:
    whole configs (e.g. the paper as published against slz's defaults) on the same recordings.

    \b
    Example:
      slz compare parking_lot.mcap --methods fuzzy,bayes -o runs/cmp
    """
    from slzcli.compare import compare, recording_name
    from slzcli.outputs.report import text_table
    from slzcli.outputs.summary_json import compare_summary

    config = _windowed(config, win_start, win_end, stride, max_frames)

    out = output or Path("runs") / f"compare_{recording_name(recordings[0])}"
    if profiles is not None:
        window = functools.partial(_windowed, start=win_start, end=win_end, stride=stride,
                                   max_frames=max_frames)
        return _compare_profiles(recordings, profiles, methods, out, variants, force, timeout_s, window)
    chosen = tuple(methods.split(",")) if methods is not None else None
    with Bar("compare", "frames", config.output.progress_every_s) as bar:
        summary = compare(list(recordings), config, out, chosen, variants=variants, force=force, progress=bar.tick,
                          timeout_s=timeout_s)
    for r in summary.recordings:
        if r.slam.maps > 1:
            log.warning("%s: SLAM lost tracking and started %d maps, each in its own frame; each method's site is "
                        "committed within one map", r.source, r.slam.maps)
        if r.slam.untracked.warning:  # more than slam.max_untracked_share of the frames without a pose
            log.warning("%s: %s", r.source, r.slam.untracked.warning)
    return envelope("compare", compare_summary(summary, str(out))), text_table(summary, str(out))


def _compare_profiles(recordings: tuple[Path, ...], profiles: str, methods: str | None, out: Path, variants: bool,
                      force: bool, timeout_s: float | None,
                      window: Callable[[Config], Config]) -> CommandResult:
    """``slz compare --profiles``: each profile's config with the command's --config and --set over it."""
    from slzcli.compare import compare_profiles
    from slzcli.errors import ConfigError
    from slzcli.outputs.report import profile_table
    from slzcli.outputs.summary_json import compare_summary

    if variants:
        raise ConfigError("--variants", "not available with --profiles (compare profiles on the variant recordings)")
    method = None
    if methods is not None:
        chosen = [m.strip() for m in methods.split(",") if m.strip()]
        if len(chosen) != 1:
            raise ConfigError("--methods", "with --profiles give one method (each profile is compared, not methods)")
        method = chosen[0]
    _, config_file, overrides = _layers()
    names = list(dict.fromkeys(n.strip() for n in profiles.split(",") if n.strip()))
    configs = {n: window(load_config(config_file, overrides, n)) for n in names}  # the same frame window each
    every_s = next(iter(configs.values())).output.progress_every_s if configs else DEFAULT_EVERY_S
    with Bar("compare", "frames", every_s) as bar:
        summary = compare_profiles(list(recordings), configs, out, method, force=force, progress=bar.tick,
                                   timeout_s=timeout_s)
    return compare_summary(summary, str(out)), profile_table(summary.rows) + \
        f"\n  results: {out}/ (compare.json, compare.csv)"


# --- commands end (new commands go above this line) ---


if __name__ == "__main__":
    main()
