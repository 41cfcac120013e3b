"""The command line's shared pieces: the one-line usage error, the parser that reports it, and
the argparse types and checks of paths and values every subcommand uses (:mod:`.`,
:mod:`.simulate`)."""
from __future__ import annotations

import argparse
import os
import pathlib
import sys
import tempfile

from ..instrument import DEAD_TIME_PRESETS_NS

PROG = "lidar-mitsuba"
#: simulate() keywords that are CLI options of their own (the rest are composed objects)
RUN_OPTIONS = ("shots", "seed", "paths_per_shot", "max_depth", "variant", "chunk_shots")


class UsageError(Exception):
    """Bad command-line input: ``option`` is the flag to name in the one-line message."""

    def __init__(self, option: str, message: str):
        super().__init__(f"{option}: {message}")


def spec_error(spec: str, e) -> UsageError:
    """A sweep's or campaign's ``SpecError`` ``e`` as a usage error naming ``spec``: "SPEC.toml:
    [grid] p: ..." (the file alone for file-wide errors)."""
    whole = e.key in ("spec", str(pathlib.Path(spec)))
    return UsageError(spec if whole else f"{spec}: {e.key}", e.message)


def connect_scheduler(address: str):
    """A ``dask.distributed.Client`` on the running scheduler at ``address`` (``--scheduler``),
    or a usage error saying why not; prints how many workers it has."""
    from dask.distributed import Client
    try:
        client = Client(address, timeout="20s")
    except (OSError, TimeoutError, ValueError) as e:
        raise UsageError("--scheduler", f"cannot connect to {address!r} ({e})") from None
    print(f"connected to {address}: {len(client.scheduler_info()['workers'])} workers")
    return client


class Parser(argparse.ArgumentParser):
    def error(self, message):   # one line, exit 2 (argparse would also print the usage)
        if message.startswith("argument "):      # "argument --shots: ..." -> "--shots: ..."
            message = message[len("argument "):]
        sys.stderr.write(f"{self.prog}: error: {message}\n")
        raise SystemExit(2)


def out_path(value: str, suffixes: tuple[str, ...], option: str = "--out") -> pathlib.Path:
    """An output file: the right suffix, not a folder, in an existing folder where a file can
    be created (tried, not guessed from permissions: root passes every permission check)."""
    path = pathlib.Path(value)
    if suffixes and path.suffix.lower() not in suffixes:
        raise UsageError(option, f"must end with {' or '.join(suffixes)} (got {value!r})")
    if path.is_dir():
        raise UsageError(option, f"{value!r} is a folder")
    parent = path.parent if str(path.parent) else pathlib.Path(".")
    if not parent.is_dir():
        raise UsageError(option, f"folder {str(parent)!r} does not exist")
    probe_writable(parent, option)
    return path


def variant_list(value: str) -> list[str]:
    """argparse type of ``bench --variant``: known, usable variants, comma-separated."""
    from ..trace.variant import usable_variants
    names = [v.strip() for v in value.split(",") if v.strip()]
    usable = usable_variants()
    bad = [v for v in names if v not in usable]
    if not names or bad:
        raise argparse.ArgumentTypeError(
            f"{', '.join(bad) or repr(value)} not available here (choose from "
            f"{', '.join(usable)})")
    return names


def out_dir(value: str, option: str = "--out") -> pathlib.Path:
    """An output folder (created by the command): not an existing file, inside a writable
    existing folder."""
    out = pathlib.Path(value)
    if out.exists() and not out.is_dir():
        raise UsageError(option, f"{value!r} exists and is not a folder")
    parent = out.parent if str(out.parent) else pathlib.Path(".")
    if not parent.is_dir():
        raise UsageError(option, f"folder {str(parent)!r} does not exist")
    probe_writable(out if out.exists() else parent, option)
    return out


def probe_writable(folder: pathlib.Path, option: str) -> None:
    """Create and remove a file in ``folder``: tried, not guessed from permissions (root passes
    every permission check, and a read-only file system fails only on writing)."""
    try:
        fd, probe = tempfile.mkstemp(prefix=".lidar-mitsuba.", suffix=".probe", dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        raise UsageError(option, f"cannot write in {str(folder)!r} ({e.strerror})") from None


def dead_time(value: str) -> float:
    if value in DEAD_TIME_PRESETS_NS:
        return DEAD_TIME_PRESETS_NS[value]
    try:
        return float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"not a number or a preset ({', '.join(DEAD_TIME_PRESETS_NS)}): {value!r}") from None


def max_depth_or_auto(value: str):
    """An argparse type: an integer or ``auto`` (``--max-depth``, ``--paths-per-shot``)."""
    if value == "auto":
        return value
    try:
        return int(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer or 'auto': {value!r}") from None


def int_at_least(minimum: int):
    """An argparse type: an integer >= ``minimum``."""
    def parse(value: str) -> int:
        try:
            v = int(value)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not an integer: {value!r}") from None
        if v < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum} (got {v})")
        return v
    return parse



positive_int = int_at_least(1)
nonnegative_int = int_at_least(0)


def define(value: str) -> tuple[str, str]:
    name, eq, v = value.partition("=")
    if not eq or not name.strip():
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE (got {value!r})")
    return name.strip(), v


def version_text() -> str:
    from ..machine import versions
    v = versions()
    return f"{PROG} {v['lidar_mitsuba']} (mitsuba {v['mitsuba']}, drjit {v['drjit']})"


def read_input(path: str, reader):
    """``reader(path)`` for the FILE argument; a missing or unreadable file is a usage error."""
    if not pathlib.Path(path).is_file():
        raise UsageError("FILE", f"{path!r} not found")
    try:
        return reader(path)
    except (OSError, ValueError, KeyError) as e:
        raise UsageError("FILE", f"cannot read {path!r} ({str(e).splitlines()[0]})") from None


def finite(obj):
    """JSON-safe copy: NaN and inf become null."""
    import math
    if isinstance(obj, dict):
        return {k: finite(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [finite(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def rates_line(r: dict) -> str:
    return (f"classifier (signal_conf_ph >= {r['min_conf']}): hit rate {r['hit_rate']:.3f} of "
            f"{r['n_signal']} signal photons, false alarms {r['false_alarm_rate']:.3f} of "
            f"{r['n_noise']} noise photons")

