"""The recorder service: `spikinglab record` / `python -m services.recorder`.

Reads:  spikinglab/<group>/state/** (the world's and the brain's state batches, the map, the
        brain's layout; one strict inbox), and the liveliness of the world and the brain
Writes: a Rerun recording (.rrd) with its default layout; optionally also to a live viewer
        (--viewer URL) or serves one (--serve); liveliness spikinglab/<group>/alive/recorder.
        One file a run: a run that follows (after the one recorded went quiet for QUIET_S, because
        it was cut short or with --forever) goes to <out>-<run id>.rrd

It ends when the world and the brain have sent their final batches (or on Ctrl-C / SIGTERM),
flushing what it has; a
recorder that is killed leaves a file that is readable up to its last flush.
"""

from __future__ import annotations

import argparse
import datetime
import logging
import os
import socket
import sys
import time
import urllib.parse
from dataclasses import dataclass
from pathlib import Path

import rerun as rr

from services.bus import keys
from services.bus.config import BusConfig, add_bus_args
from services.bus.schemas import BrainLayout, BrainState, WorldMap, WorldState
from services.bus.transport import Bus
from services.options import Parser, agent_list, at_least, ip_address, output_file, port, whole_within
from services.runtime import service_main

from .listener import Listener
from .recorder import Recorder, blueprint
from .screenshot import is_recording

log = logging.getLogger("spikinglab.recorder")


def parser() -> argparse.ArgumentParser:
    p = Parser(prog="spikinglab record", description="Record a run to a Rerun file.")
    p.together = [lambda args: p.mode_defaults(args, "--web" if args.web else "--serve" if args.serve else "", LIVE)]
    p.add_argument(
        "--out",
        type=recording_out,
        help="the .rrd file (default runs/<date>-<time>/recording.rrd; an earlier one there is kept as "
        "<name>.previous.rrd; a file there that is not a recording is refused)",
    )
    p.add_argument(
        "--viewer",
        metavar="URL",
        type=viewer_url,
        help="also stream to a running viewer, e.g. rerun+http://127.0.0.1:9876/proxy",
    )
    live = p.add_argument_group("live view")
    live.add_argument(
        "--serve",
        action="store_true",
        help="also serve the run live over gRPC for viewers: rerun rerun+http://HOST:GRPC_PORT/proxy",
    )
    live.add_argument(
        "--web",
        action="store_true",
        help="also host the web viewer over HTTP, showing the served run (implies --serve)",
    )
    # no defaults here: LIVE's, so that one given without the live view is refused, not ignored
    live.add_argument(
        "--grpc-host",
        type=ip_address,
        help="the address --serve listens on (default 0.0.0.0: every interface; 127.0.0.1: this machine only)",
    )
    live.add_argument("--grpc-port", type=port, help="--serve's port (default 9876)")
    live.add_argument("--web-port", type=port, help="--web's port (default 9090)")
    p.add_argument(
        "--detail",
        default=(0,),
        type=agent_list,
        help="agents with raster, potentials, weights, ray, trail, e.g. 0,3 (default 0)",
    )
    p.add_argument("--flush-every", type=at_least(1), default=1000, help="ticks per batch written (default 1,000)")
    p.add_argument("--forever", action="store_true", help="keep recording after the run's end")
    p.add_argument(
        "--backlog-mb",
        type=at_least(1),
        default=256,
        help="messages waiting to be recorded, at most (default %(default)s MB): beyond, they are dropped "
        "and counted, and the ticks missing are said; a recorder that falls behind never holds the "
        "run back nor grows without limit",
    )
    p.add_argument(
        "--nice",
        type=whole_within(-20, 19, " (the range of a process's niceness)"),
        default=10,
        help="scheduling priority increment, -20 .. 19 (default 10: after world and brain)",
    )
    add_bus_args(p)
    return p


# the live view's options: (default, the modes that use them) for Parser.mode_defaults
LIVE = {
    "--grpc-host": ("0.0.0.0", ("--serve", "--web")),
    "--grpc-port": (9876, ("--serve", "--web")),
    "--web-port": (9090, ("--web",)),
}


@dataclass(frozen=True)
class RecorderConfig:
    """The recorder's options (parser()), typed: what run() and its parts take."""

    out: Path | None
    viewer: str | None
    serve: bool
    web: bool
    grpc_host: str
    grpc_port: int
    web_port: int
    detail: tuple[int, ...]
    flush_every: int
    forever: bool
    backlog_mb: int
    nice: int
    bus: BusConfig


def recording_out(text: str) -> Path:
    """--out: a file to write, and one that holds something other than a recording is the user's:
    refused rather than moved aside (keep_earlier) and replaced. An empty file holds nothing."""
    path = output_file(text)
    if path.is_file() and path.stat().st_size > 0 and not is_recording(path):
        raise argparse.ArgumentTypeError(f"{text} is not a Rerun recording (.rrd): refusing to replace it")
    return path


def viewer_url(text: str) -> str:
    """A viewer's gRPC URL (rerun+http://host:port/proxy), checked before anything starts."""
    url = urllib.parse.urlsplit(text)
    if url.scheme not in ("rerun", "rerun+http", "rerun+https") or not url.hostname:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a viewer URL: expected rerun+http://HOST:PORT/proxy, "
            "e.g. rerun+http://127.0.0.1:9876/proxy"
        )
    return text


def web_viewer_url(web_port: int, grpc_port: int, host: str = "127.0.0.1") -> str:
    """The page of the web viewer at web_port showing the run served at grpc_port."""
    source = urllib.parse.quote(f"rerun+http://{host}:{grpc_port}/proxy", safe="")
    return f"http://{host}:{web_port}/?url={source}"


def free_port(preferred: int) -> int:
    """`preferred` if nothing listens there, else any free port."""
    with socket.socket() as s:
        try:
            s.bind(("0.0.0.0", preferred))
        except OSError:
            s.bind(("0.0.0.0", 0))
        return s.getsockname()[1]


def viewer_answers(text: str, timeout: float = 3.0) -> bool:
    url = urllib.parse.urlsplit(text)
    port = url.port or (443 if url.scheme.endswith("https") else 9876)
    try:
        socket.create_connection((url.hostname, port), timeout=timeout).close()
        return True
    except OSError:
        return False


def run(config: RecorderConfig, session) -> int:
    if not can_serve(config):
        return 1
    serve, group = config.serve or config.web, config.bus.group
    out = config.out or Path("runs") / f"{datetime.datetime.now():%Y%m%d-%H%M%S}" / "recording.rrd"
    out.parent.mkdir(parents=True, exist_ok=True)
    keep_earlier(out)
    rec = open_recording(config, out, f"{group}-{out.parent.name}", serving=serve)
    if serve:
        log.info("serving the run live: rerun rerun+http://127.0.0.1:%d/proxy", config.grpc_port)
    if config.web:
        rr.serve_web_viewer(
            web_port=config.web_port, open_browser=False, connect_to=f"rerun+http://127.0.0.1:{config.grpc_port}/proxy"
        )
        log.info("web viewer: %s", web_viewer_url(config.web_port, config.grpc_port))
    bus = Bus(session, group, "recorder")
    recorder = Recorder(rec, detail=config.detail, flush_every=config.flush_every)
    # only the state streams: the lock-step messages (sensors, motor) never come to the recorder
    inbox = bus.inbox(
        keys.state(group), (WorldMap, WorldState, BrainState, BrainLayout), backlog_bytes=config.backlog_mb << 20
    )
    watched = {name: bus.presence(name) for name in ("world", "brain")}

    def open_next(path: Path, run_id: str) -> rr.RecordingStream:
        return open_recording(config, path, f"{group}-{run_id}", served_at=serve and config.grpc_port)

    listener = Listener(inbox, watched, rec, recorder, out, group, config.forever, open_next)
    bus.watch_others(lambda: f" (recorded up to tick {listener.recorder.last_tick})")
    recorder.event(f"recorder started on group {group}, writing {out}")
    log.info("recording group %s to %s", group, out)
    try:
        while not listener.step(inbox.get(timeout=0.25)):
            pass
    finally:
        listener.close()
        bus.close()
        took = max(time.monotonic() - listener.first_at, 1e-9)
        log.info(
            "recording written to %s (%s): %d messages in %.1f s, %s messages/s; ticks missing: %s; rejected: %s",
            listener.current,
            listener.recorder.ticks_held(),
            listener.received,
            took,
            f"{listener.received / took:,.{0 if listener.received >= 10 * took else 2}f}",  # a slow stream too
            listener.recorder.missing or "none",
            bus.rejections() or "none",
        )
        if listener.received == 0:
            log.warning(
                "no state came: a recording holds what the world and the brain publish with --publish-state "
                "(a gateway publishes none)"
            )
    return 0


def can_serve(config: RecorderConfig) -> bool:
    """Whether the viewer to stream to answers and the ports to serve on are free (says why not)."""
    if config.viewer and not viewer_answers(config.viewer):
        log.error("no viewer answers at %s (start one with `rerun`, or leave out --viewer)", config.viewer)
        return False
    serve = config.serve or config.web
    for wanted, number, option in (
        (serve, config.grpc_port, "--grpc-port"),
        (config.web, config.web_port, "--web-port"),
    ):
        if wanted and free_port(number) != number:
            log.error("port %d is in use: nothing can be served there (choose another with %s)", number, option)
            return False
    return True


def keep_earlier(out: Path) -> None:
    """An earlier recording at `out` (a launch file's fixed --out) moved to <name>.previous.rrd: a
    run that ends before its first tick must not leave an empty file in its place. (A file there
    that is not a recording never comes here: --out refuses it.)"""
    if out.is_file() and out.stat().st_size > 0:
        kept = out.with_name(f"{out.stem}.previous{out.suffix}")
        out.replace(kept)
        log.info("%s held an earlier recording: kept as %s", out, kept)


def open_recording(
    config: RecorderConfig, path: Path, recording_id: str, serving: bool = False, served_at: int | None = None
) -> rr.RecordingStream:
    """A recording written to `path`, streamed to --viewer, and served live (`serving`: this
    recording's stream serves at --grpc-port; `served_at`: sent to the one that serves there)."""
    rec = rr.RecordingStream("spikinglab", recording_id=recording_id)
    sinks: list = [rr.FileSink(str(path))]
    if config.viewer:
        sinks.append(rr.GrpcSink(config.viewer))
    if serving:  # beside the file: the recording is written whoever watches
        sinks.append(rr.GrpcServerSink(bind_ip=config.grpc_host, port=config.grpc_port))
    elif served_at:
        sinks.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{served_at}/proxy"))
    rec.set_sinks(*sinks, default_blueprint=blueprint(config.detail[0] if config.detail else 0))
    return rec


def step_back(config: RecorderConfig) -> None:
    """Run behind the lock-step pair (--nice); the recorder buffers (losslessly) and catches up."""
    try:
        os.nice(config.nice)
    except OSError as e:  # a negative increment needs root or CAP_SYS_NICE: record at the usual priority
        log.warning(
            "cannot change the priority by --nice %d (%s): recording at the usual priority", config.nice, e.strerror
        )


def main(argv=None) -> int:
    return service_main("recorder", parser(), run, argv, interrupted=0, prepare=step_back, config=RecorderConfig)


if __name__ == "__main__":
    sys.exit(main())
