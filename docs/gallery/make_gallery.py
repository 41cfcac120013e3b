"""Regenerate the gallery's images: run every ``lidar-mitsuba`` command of
``docs/gallery/index.md`` (from the repository root, as the page shows them), with the files
they write in a temporary folder and their ``--plot`` PNG here, then every Python block of the
page (in this folder: the PNG it writes lands here).

    python docs/gallery/make_gallery.py            # every command (about four minutes)
    python docs/gallery/make_gallery.py fog.png    # only the commands that draw fog.png
"""
from __future__ import annotations

import os
import pathlib
import sys
import tempfile
import time

HERE = pathlib.Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path[:0] = [str(ROOT), str(HERE.parent / "_ext")]
os.environ.setdefault("MPLBACKEND", "Agg")

from doc_commands import code_blocks, commands, redirect_outputs  # noqa: E402

MAX_PNG_BYTES = 150_000


def shrink(path: pathlib.Path, colors: int = 64) -> int:
    """Rewrite a PNG with a palette of ``colors`` (a plot has few): a third of its bytes."""
    from PIL import Image
    with Image.open(path) as im:
        small = im.convert("RGB").quantize(colors=colors, method=Image.Quantize.MEDIANCUT)
    small.save(path, format="PNG", optimize=True)
    return path.stat().st_size


def main(only: list[str]) -> int:
    from lidar_mitsuba_cli import main as cli
    os.chdir(ROOT)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        for cmd in commands(HERE / "index.md"):
            pngs = [a for a in cmd.argv if a.endswith(".png")]
            if only and cmd.argv[0] != "make-dem" and not set(pngs) & set(only):
                continue
            argv = redirect_outputs(cmd.argv, tmp, keep={p: HERE / p for p in pngs})
            t = time.perf_counter()
            code = cli(argv + (["--no-progress"] if cmd.subcommand == "simulate" else []))
            print(f"{cmd} -> {code} ({time.perf_counter() - t:.1f} s)", flush=True)
            if code:
                return code
            for p in pngs:
                size = shrink(HERE / p)
                if size > MAX_PNG_BYTES:
                    print(f"warning: {p} is {size} bytes (> {MAX_PNG_BYTES})")
    return run_python_blocks(only)


def run_python_blocks(only: list[str]) -> int:
    """Run each Python block of the page that draws a selected PNG (all when none is
    selected), in this folder, and shrink what it drew."""
    import re
    os.chdir(HERE)
    for lang, line, body in code_blocks(HERE / "index.md"):
        source = "\n".join(body)
        pngs = re.findall(r"[\w.-]+\.png", source)
        if lang != "python" or (only and not set(pngs) & set(only)):
            continue
        t = time.perf_counter()
        exec(compile(source, f"index.md:{line}", "exec"), {"__name__": "__gallery__"})
        print(f"index.md:{line} -> {', '.join(pngs)} ({time.perf_counter() - t:.1f} s)")
        for p in pngs:
            size = shrink(HERE / p)
            if size > MAX_PNG_BYTES:
                print(f"warning: {p} is {size} bytes (> {MAX_PNG_BYTES})")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
