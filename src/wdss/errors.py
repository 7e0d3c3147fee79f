"""Input wdss refuses, and how its entry points say so: one line naming the key, file, frame or checkpoint.

Every error a user can fix by changing what they passed (a config key, a data folder, an EXR file, a checkpoint, a
``_target_``) derives from :class:`UserError`. The ``python -m wdss.*`` entry points print it as one line,
``<command>: <message>``, and exit with status 2 (:func:`entry_point`, which also answers a mistyped config key
with the closest keys rather than Hydra's "use +key"); anything else is a bug and keeps its traceback. The job's
Hydra output folder is removed when the refusal left nothing in it but Hydra's own record, so that a mistyped
command leaves no folder that looks like a run. In a Hydra sweep the error is raised as it is, so that Hydra reports
which job failed.

While an entry point runs, what it prints also goes to the job's Hydra log file (:mod:`wdss.logfile`), and so does
how it ended: the one line of a refusal (but for a removed folder), or the traceback of a bug.
"""

from __future__ import annotations

import difflib
import functools
import inspect
import logging
import os
import shutil
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TypeVar

from wdss.logfile import log_exception, teed_output, to_log_file

__all__ = ["ConfigError", "UserError", "check_built", "check_overrides", "entry_point", "one_line_errors"]

F = TypeVar("F", bound=Callable[..., Any])


class UserError(ValueError):
    """Input that cannot be used as given; the message names it and says what would work."""


class ConfigError(UserError):
    """A configuration that cannot describe a valid run (the message names the key)."""


def _multirun() -> bool:
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    return HydraConfig.initialized() and HydraConfig.get().mode == RunMode.MULTIRUN


def _remove_empty_output_dir() -> bool:
    """Remove this job's Hydra output folder if it holds only ``.hydra/`` and empty log files (what Hydra writes
    before the task runs): a refused command leaves no run folder behind. Whether it did."""
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import OmegaConf

    if not HydraConfig.initialized():
        return False
    output_dir = OmegaConf.select(HydraConfig.get(), "runtime.output_dir")  # None: a config composed, not run
    if output_dir is None or not Path(output_dir).is_dir():
        return False
    folder = Path(output_dir)
    for entry in folder.iterdir():
        if entry.name == ".hydra" and entry.is_dir():
            continue
        if entry.suffix == ".log" and entry.is_file() and entry.stat().st_size == 0:
            continue
        return False  # the job wrote something: keep it
    shutil.rmtree(folder, ignore_errors=True)
    return True


def one_line_errors(command: str) -> Callable[[F], F]:
    """Decorate an entry point (inside ``@hydra.main``): a :class:`UserError` becomes ``command: message`` on
    stderr and exit status 2, instead of a traceback. What the entry point prints, and how it ended, also go to the
    job's log file."""

    def wrap(main: F) -> F:
        @functools.wraps(main)
        def guarded(*args: Any, **kwargs: Any) -> Any:
            try:
                with teed_output(command):
                    return main(*args, **kwargs)
            except UserError as err:
                line = f"{command}: {err}"
                if _multirun():
                    to_log_file(line, logging.ERROR, command)
                    raise
                print(line, file=sys.stderr, flush=True)
                if not _remove_empty_output_dir():
                    to_log_file(line, logging.ERROR, command)
                raise SystemExit(2) from None
            except SystemExit:
                raise
            except BaseException as err:
                log_exception(err, command)
                raise

        return guarded  # type: ignore[return-value]

    return wrap


def _closest(key: str, cfg: Any) -> str:
    """``did you mean ...`` for an unknown dotted ``key`` of ``cfg``: the closest keys beside it."""
    from omegaconf import DictConfig, OmegaConf

    parent, _, leaf = key.rpartition(".")
    node = OmegaConf.select(cfg, parent) if parent else cfg
    if not isinstance(node, DictConfig):
        return ""
    keys = [str(k) for k in node]
    near = difflib.get_close_matches(leaf, keys, n=3, cutoff=0.6)
    prefix = f"{parent}." if parent else ""
    if near:
        return f" (did you mean {' or '.join(prefix + k for k in near)}?)"
    return f" ({parent or 'the config'} has: {', '.join(sorted(keys))})"


def check_overrides(command: str, config_dir: str | Path, config_name: str, argv: Sequence[str]) -> None:
    """Compose the config as Hydra will and answer an override of a key that does not exist with one line naming
    the closest keys, exit status 2 (Hydra's own message advises ``+key=value``, which adds the typo as a new key).
    Command lines with Hydra flags other than ``-cn`` (``--multirun``, ``--cfg``, ``--help``) are left to Hydra,
    as is any other composition error (its messages name the group and its options)."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.errors import ConfigCompositionException
    from omegaconf.errors import ConfigAttributeError, ConfigKeyError

    overrides, name, args = [], config_name, list(argv)
    while args:
        arg = args.pop(0)
        if arg in ("-cn", "--config-name") and args:
            name = args.pop(0)
        elif arg.startswith("--config-name="):
            name = arg.partition("=")[2]
        elif arg.startswith("-"):
            return
        else:
            overrides.append(arg)
    if GlobalHydra.instance().is_initialized():
        return  # inside a Hydra app (a test or a notebook that composed already): Hydra reports

    def composed(items: list[str]) -> Any:
        try:
            with initialize_config_dir(config_dir=str(config_dir), version_base="1.3", job_name=command):
                return compose(name, overrides=items)
        finally:
            GlobalHydra.instance().clear()

    try:
        composed(overrides)
    except ConfigCompositionException as err:
        cause = err.__cause__
        if not (
            isinstance(cause, ConfigAttributeError | ConfigKeyError)
            and "not in struct" in str(cause)
            and cause.full_key
        ):
            return
        key = str(cause.full_key)
        rest = [o for o in overrides if not f"{o.partition('=')[0].lstrip('~+')}.".startswith(f"{key}.")]
        try:
            hint = _closest(key, composed(rest))
        except Exception:  # another override fails too: name the key without a hint
            hint = ""
        print(f"{command}: unknown config key {key}{hint}", file=sys.stderr, flush=True)
        raise SystemExit(2) from None
    except Exception:  # noqa: BLE001 - anything else is Hydra's to report, with its own message
        return


# What Hydra builds from its own node: from the config before the sweep, or (logging) per job, unchecked there.
_HYDRA_BUILT = ("hydra.callbacks", "hydra.launcher", "hydra.sweeper", "hydra.job_logging", "hydra.hydra_logging")


def check_built(
    command: str, config_dir: str | Path, config_name: str, argv: Sequence[str], task_file: str | None = None
) -> None:
    """Compose the config as Hydra will (its own parser: ``-cd``, ``-cn``, ``--multirun``), with its ``hydra``
    node, and answer anything that Hydra or wdss would build outside its slot's allowlist
    (:func:`wdss.config.targets.check_config`: hydra.callbacks, launcher, sweeper and logging classes too) with one line
    naming the key, exit status 2: Hydra builds its callbacks and logging before any task code runs. A command
    line Hydra cannot parse or compose is left to Hydra, which reports it."""
    from hydra._internal.hydra import Hydra
    from hydra._internal.utils import create_automatic_config_search_path, get_args_parser
    from hydra.core.global_hydra import GlobalHydra
    from hydra.types import RunMode
    from omegaconf import OmegaConf

    from wdss.config.targets import TargetRefused, check_config

    if GlobalHydra.instance().is_initialized():
        return  # inside a Hydra app (a test or a notebook that composed already)
    try:
        args = get_args_parser().parse_args(list(argv))
    except SystemExit:
        return
    if args.help or args.hydra_help or args.shell_completion:
        return
    config_path = str(config_dir)
    if args.config_path is not None:  # as Hydra takes it: relative to the entry point's file
        config_path = os.path.join(os.path.dirname(task_file or sys.argv[0]), args.config_path)
    search_path = create_automatic_config_search_path(None, None, os.path.abspath(config_path))
    if args.config_dir is not None:
        from hydra.core.config_search_path import SearchPathQuery

        search_path.prepend("command-line", f"file://{os.path.abspath(args.config_dir)}", SearchPathQuery("schema"))
    try:
        hydra = Hydra.create_main_hydra2(task_name=command, config_search_path=search_path)
        # Multirun: a sweep's values are the jobs' (each job's task checks its own config), the rest applies now.
        cfg = hydra.compose_config(args.config_name or config_name, args.overrides, run_mode=RunMode.MULTIRUN)
    except Exception:  # noqa: BLE001 - Hydra reports it, with its own message
        return
    finally:
        GlobalHydra.instance().clear()
    # Hydra refuses a command line's sweep over its own nodes, not one in hydra.sweeper.params.
    for key in (str(k).lstrip("+~") for k in OmegaConf.select(cfg, "hydra.sweeper.params") or {}):
        if any(f"{key}.".startswith(f"{built}.") for built in _HYDRA_BUILT):
            print(f"{command}: hydra.sweeper.params sweeps {key}, which Hydra builds: set it once", file=sys.stderr)
            raise SystemExit(2)
    try:
        check_config(cfg)
    except TargetRefused as err:
        print(f"{command}: {err}", file=sys.stderr, flush=True)
        raise SystemExit(2) from None


def entry_point(command: str, config_dir: str | Path, config_name: str) -> Callable[[F], Callable[..., Any]]:
    """``@hydra.main`` for a ``python -m wdss.*`` command: a mistyped key is one line with the closest keys
    (:func:`check_overrides`), a target off its slot's allowlist, the ``hydra`` node's included, is refused before
    Hydra builds anything (:func:`check_built`), and a :class:`UserError` is one line and exit status 2
    (:func:`one_line_errors`)."""
    import hydra

    def wrap(task: F) -> Callable[..., Any]:
        hydra_main = hydra.main(version_base="1.3", config_path=str(config_dir), config_name=config_name)(
            one_line_errors(command)(task)
        )

        @functools.wraps(task)
        def main(cfg_passthrough: Any = None) -> Any:
            if cfg_passthrough is None:
                check_overrides(command, config_dir, config_name, sys.argv[1:])
                check_built(command, config_dir, config_name, sys.argv[1:], inspect.getfile(task))
            return hydra_main(cfg_passthrough)

        return main

    return wrap
