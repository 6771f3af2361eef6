"""`spikinglab screenshot RRD`: a PNG of a recording's replay, rendered by a headless viewer.

Needs a Vulkan driver; on a machine without a GPU, Mesa's software one (Debian:
`apt-get install mesa-vulkan-drivers libvulkan1`). The viewer opens the file in its stored layout,
the time cursor is set to --tick (default: the end), and the window is saved.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import socket
import subprocess
import sys
import time
import warnings
from pathlib import Path

import rerun.experimental as rrx
from rerun.chunk import RrdReader
from rerun.error_utils import RerunWarning

from services.options import Parser, at_least, output_file
from services.run_folder import recording_parts

from .viewer import viewer_command

RRD_MAGIC = b"RRF2"  # the first bytes of a Rerun recording
# what the viewer says when it found nothing to render with (no Vulkan driver; wgpu's GL fallback fails too)
NO_RENDERER = re.compile(r"render context|render state|graphics adapter|wgpu adapter")
ANSI_COLOUR = re.compile(r"\x1b\[[0-9;]*m")
# Rust's backtrace and rerun's footer of links: nothing of why it stopped
NOT_WHY = re.compile(r"stack backtrace:|\s*\d+: |\s+at |Troubleshooting Rerun:|Report bugs:")


def is_recording(path: Path) -> bool:
    """Whether the file starts as a Rerun recording does (it may still be cut short)."""
    with open(path, "rb") as f:
        return f.read(len(RRD_MAGIC)) == RRD_MAGIC


def last_tick(path: Path) -> int:
    last = 0
    for chunk in RrdReader(str(path)).stream():
        batch = chunk.to_record_batch()
        if "tick" in batch.schema.names and batch.num_rows:
            last = max(last, max(batch.column("tick").to_pylist()))
    return last


def recorded_until(path: Path) -> int:
    """last_tick of a recording that a screenshot is asked of; ValueError, in a line, for a file
    that is not one or one cut short. A killed writer's file without its footer is read as it is."""
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", "RRD file has no footer", RerunWarning)
            return last_tick(path)
    except RuntimeError as e:  # rerun's reader
        why = str(e).splitlines()[0].removeprefix(f"Failed to read RRD file at {path}: ")
    if not is_recording(path):
        raise ValueError(f"not a Rerun recording (.rrd): {why}")
    raise ValueError(
        f"a damaged Rerun recording, cut short as a writer killed mid-write leaves it ({why}); "
        f"`rerun rrd optimize {path} -o repaired.rrd` keeps what it holds"
    )


def repair(recording: Path) -> bool:
    """Give a recording whose writer was killed (no footer: Rerun can stream it but not open it as
    a store) its footer back, in place; True if it was repaired."""
    command = viewer_command()
    if command is None:
        return False
    fixed = recording.with_name(recording.name + ".repaired.rrd")
    done = subprocess.run([*command, "rrd", "optimize", str(recording), "-o", str(fixed)], capture_output=True)
    if done.returncode != 0 or not fixed.exists():
        fixed.unlink(missing_ok=True)
        return False
    fixed.replace(recording)
    return True


def screenshot(
    recording: Path, out: Path, tick: int | None = None, size: str = "1600x900", settle: float = 2.0
) -> Path:
    """Render `recording` at `tick` into `out` (PNG) with a headless viewer."""
    tick = last_tick(recording) if tick is None else tick
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    command = viewer_command()
    if command is None:
        raise RuntimeError("no Rerun viewer: the rerun command comes with rerun-sdk (pip install rerun-sdk)")
    viewer = subprocess.Popen(
        [*command, "--headless", "--window-size", size, "--port", str(port), "--hide-welcome-screen"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )  # its own group: the venv's `rerun` starts the real viewer
    try:
        client = connected(viewer, port)
        try:
            client.open(str(recording.resolve()))
            time.sleep(settle)  # panels are still empty if captured at once
            client.set_time("tick", sequence=tick, play_state="paused")
            time.sleep(settle)
            out.parent.mkdir(parents=True, exist_ok=True)
            client.save_screenshot(str(out.resolve()))
        except ConnectionError as e:  # the viewer's answer to a request it cannot carry out, or its end
            refused = f"the viewer could not show {recording} at tick {tick}: {str(e).splitlines()[0]}"
            raise RuntimeError(why_it_ended(viewer) or refused) from None
    finally:  # the whole group: killing the wrapper alone left a ~400 MB viewer behind per call
        try:
            os.killpg(viewer.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        viewer.wait()
    return out


def connected(viewer: subprocess.Popen, port: int) -> rrx.ViewerClient:
    """A client of the headless viewer once it answers at `port`; RuntimeError if it ends first."""
    deadline = time.monotonic() + 30
    while True:
        if viewer.poll() is not None:
            raise RuntimeError(why_it_stopped(viewer.stderr.read() if viewer.stderr else ""))
        try:
            client = rrx.ViewerClient(f"rerun+http://127.0.0.1:{port}/proxy")
            client.get_state()
            return client
        except Exception:  # not listening yet
            if time.monotonic() > deadline:
                raise RuntimeError("the headless viewer did not start within 30 s") from None
            time.sleep(0.2)


def why_it_ended(viewer: subprocess.Popen) -> str | None:
    """why_it_stopped, if the viewer ends within a few seconds (a request can fail before the viewer's
    panic ends it: it failed to render its first frame); None if it goes on."""
    try:
        return why_it_stopped(viewer.communicate(timeout=5)[1] or "")
    except subprocess.TimeoutExpired:
        return None


def why_it_stopped(stderr: str, lines: int = 6) -> str:
    """What the headless viewer's stderr says of its end: without a graphics driver, that and the
    fix (in one line); else its last lines, whole, without Rust's backtrace."""
    text = ANSI_COLOUR.sub("", stderr)
    if NO_RENDERER.search(text):
        return (
            "the headless viewer found no graphics driver to render with: it needs Vulkan, and without a GPU "
            "Mesa's software driver (Debian: apt-get install mesa-vulkan-drivers libvulkan1)"
        )
    said = [line for line in text.splitlines() if line.strip() and not NOT_WHY.match(line)]
    return "the headless viewer stopped:\n" + "\n".join(said[-lines:])


def window_size(text: str) -> str:
    """A --size option: WIDTHxHEIGHT in points, e.g. 1600x900."""
    width, _, height = text.partition("x")
    if not (width.isdigit() and height.isdigit() and int(width) > 0 and int(height) > 0):
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT in points, e.g. 1600x900; got {text!r}")
    return text


def png_file(text: str) -> Path:
    """--out: a PNG file that can be written (the viewer picks the format by the name)."""
    path = output_file(text)
    if path.suffix.lower() != ".png":
        raise argparse.ArgumentTypeError(f"{text}: a screenshot is a PNG file, named .png")
    return path


def main(argv=None) -> int:
    p = Parser(prog="spikinglab screenshot", description=(__doc__ or "").splitlines()[0])
    p.add_argument("recording", type=Path)
    p.add_argument("--out", type=png_file, help="PNG file (default: beside the recording, replay.png)")
    p.add_argument("--tick", type=at_least(0), help="where the time cursor goes (default: the last tick)")
    p.add_argument("--size", type=window_size, default="1600x900", help="window size in points (default 1600x900)")
    args = p.parse_args(argv)
    if not args.recording.is_file():
        what = "a folder; expected a recording (.rrd)" if args.recording.is_dir() else "no such recording"
        print(f"spikinglab screenshot: {args.recording}: {what}", file=sys.stderr)
        return 2
    try:
        last = recorded_until(args.recording)  # read whatever --tick says: it also tells a recording from other files
    except ValueError as e:
        print(f"spikinglab screenshot: {args.recording}: {e}", file=sys.stderr)
        return 2
    if args.tick is not None and args.tick > last:
        later = [path for path, start in recording_parts(args.recording.parent).items() if last < start <= args.tick]
        held = f"; {later[-1]}, a later part of the run, holds it" if later else ""
        p.error(f"argument --tick: {args.tick:,} is beyond the recording's last tick, {last:,}{held}")
    try:
        out = screenshot(
            args.recording,
            args.out or args.recording.with_name("replay.png"),
            last if args.tick is None else args.tick,
            args.size,
        )
    except RuntimeError as e:  # the headless viewer could not start or render
        print(f"spikinglab screenshot: {e}", file=sys.stderr)
        return 1
    print(f"screenshot written to {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
