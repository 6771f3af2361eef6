"""`spikinglab launch FILE`: start the services a launch file names, show their logs, end them together.

This module is the one way to start a service process in the code base: `run`, `launch`, the
benchmarks and the tests all call `spawn()` or a `Launcher`. A launch file (TOML, docs/launch.md)
has one table per process, started in file order; its keys are the service's own options (the
same names as on its command line, checked by the service's own parser before anything starts):

    [launch]
    until = "world"            # the launch ends when this process ends (default: when all have)

    [world]                    # a process named "world"; `service` defaults to the table's name
    listen = ["tcp/127.0.0.1:7447"]
    ticks = 20000

    [brain]
    connect = ["tcp/127.0.0.1:7447"]
    once = true
"""

from __future__ import annotations

import argparse
import collections
import importlib
import itertools
import logging
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

from services.brain.brain import check_sensors
from services.brain.checkpoint import load_weights
from services.brain.circuit import load_circuit
from services.commands import ENDLESS, PARENT, SERVICES
from services.interrupts import ctrl_c_held
from services.options import Parser, UsageError, output_folder
from services.params import file_for_agents, read_params
from services.world.world import SENSORS

log = logging.getLogger("spikinglab.launch")
COLOURS = (36, 33, 35, 32, 34, 31)  # ANSI: cyan, yellow, magenta, green, blue, red
ENDING_S = 5.0  # a process that ends before `until` is an error only if `until` has not ended this much later
PROGRESS_S = 5.0  # a progress bar's state is shown this often (it redraws itself many times a second)
FINISH_S = 120.0  # after the `until` process ended: how long the others may take to end by themselves
STOP_S = 30.0  # after SIGTERM: how long a service may take to write what it has (the world's metrics)


class LaunchError(Exception):
    """A launch file or process that cannot be started: the message names the file, table and key."""


@dataclass
class Process:
    """One service process: `options` are its command-line options by name (`ticks`, `connect`,
    ...; True is a flag, a list repeats the option), `log` a file for its output (None: its lines
    on the terminal, prefixed with its name), `raw` its output on the terminal as it is (a
    progress bar)."""

    name: str
    service: str
    options: dict = field(default_factory=dict)
    log: Path | None = None
    raw: bool = False

    def argv(self) -> list[str]:
        out = []
        for key, value in self.options.items():
            flag = "--" + key.replace("_", "-")
            if value is True:
                out.append(flag)
            elif isinstance(value, (list, tuple)):
                out += [f"{flag}={item}" for item in value]  # one argument each: a value may begin with '-'
            elif value is not False and value is not None:
                out.append(f"{flag}={value}")
        return out

    def check(self, where: str = "") -> argparse.Namespace:
        """The options as the service's own parser reads them; LaunchError names what is wrong."""
        where = where or self.name
        if self.service not in SERVICES:
            raise LaunchError(f"{where}: unknown service {self.service!r} (one of {', '.join(SERVICES)})")
        parser = importlib.import_module(SERVICES[self.service]).parser()
        parser.exit_on_error = False  # raise, so that the error can name the launch file
        self.check_kinds(parser, where)
        try:
            return parser.parse_args(self.argv())
        except (argparse.ArgumentError, UsageError) as e:
            raise LaunchError(f"{where}: {e}") from None

    def check_kinds(self, parser: argparse.ArgumentParser, where: str) -> None:
        """What argv() would let through to a wrong meaning: a switch given a value other than true
        or false (`--flag yes` ends as an unrecognised `yes`), a list for an option taken once (the
        last would win)."""
        actions = {flag: action for action in parser._actions for flag in action.option_strings}
        for key, value in self.options.items():
            action = actions.get("--" + key.replace("_", "-"))
            if action is None:
                continue  # the parser names it
            if isinstance(action, argparse._HelpAction):  # it would print the help and start nothing
                raise LaunchError(f"{where}: {key}: not an option of a process (spikinglab {self.service} --help)")
            if action.nargs != 0 and isinstance(value, bool):  # false would leave the default, silently
                raise LaunchError(f"{where}: {key} = {str(value).lower()}: takes a value, not true or false")
            if action.nargs == 0 and not isinstance(value, bool):
                raise LaunchError(f"{where}: {key} = {value!r}: a switch, true or false")
            if isinstance(value, (list, tuple)) and not isinstance(action, argparse._AppendAction):
                raise LaunchError(f"{where}: {key} = {value!r}: takes one value, not a list")


def local_endpoints(*names: str) -> tuple[list[str], tempfile.TemporaryDirectory]:
    """Unix-socket endpoints for processes on this machine (5-10 % faster lock-step than TCP
    loopback); the socket files live in a short temporary folder (paths are limited to 108 bytes)."""
    folder = tempfile.TemporaryDirectory(prefix="spikinglab-")
    return [f"unixsock-stream/{folder.name}/{n}.sock" for n in names], folder


def options_for(service: str, args: argparse.Namespace) -> dict:
    """The options in `args` (another command's, e.g. run's) that `service` has too, by name: run
    declares them with the service's own add_*_args, so the name means the same in both."""
    own = {action.dest for action in importlib.import_module(SERVICES[service]).parser()._actions} - {"help"}
    return {name: value for name, value in vars(args).items() if name in own}


def spawn(
    service: str,
    argv: list,
    output: Path | int | None = None,
    cwd: Path | None = None,
    env: dict[str, str] | None = None,
) -> subprocess.Popen:
    """`python -m <service's module> argv` in a session of its own: Ctrl-C in the terminal reaches
    only the launcher, which ends the services in order (the world first, so that it writes the
    ticks done). It ends when this process dies (services.runtime.end_with_parent). Output (stdout
    and stderr) goes to the file `output`, to the terminal as it is (None), or to subprocess.PIPE /
    DEVNULL. `env`: variables set for this process only."""
    command = [sys.executable, "-m", SERVICES.get(service, service), *map(str, argv)]
    env = dict(os.environ, PYTHONUNBUFFERED="1", **{PARENT: str(os.getpid())}, **(env or {}))
    if isinstance(output, Path):
        with open(output, "a") as out:  # closed here once started: the child has its own copy
            return subprocess.Popen(
                command, stdout=out, stderr=subprocess.STDOUT, env=env, cwd=cwd, start_new_session=True
            )
    stderr = None if output is None else subprocess.STDOUT
    return subprocess.Popen(command, stdout=output, stderr=stderr, env=env, cwd=cwd, start_new_session=True)


def stop(popen: subprocess.Popen, timeout: float = STOP_S) -> bool:
    """SIGTERM (a service writes what it has, as on Ctrl-C), then SIGKILL after `timeout`. Whether
    it ended by itself."""
    return stop_together([popen], timeout) == []


def stop_together(popens: list[subprocess.Popen], timeout: float = STOP_S) -> list[int]:
    """SIGTERM to each at once, then SIGKILL to those still running `timeout` s later: the places
    in `popens` of those killed."""
    for popen in popens:
        if popen.poll() is None:
            popen.terminate()
    deadline, killed = time.monotonic() + timeout, []
    for k, popen in enumerate(popens):
        try:
            popen.wait(max(deadline - time.monotonic(), 0.0))
        except subprocess.TimeoutExpired:
            popen.kill()
            popen.wait()
            killed.append(k)
    return killed


class Child:
    """A started process, and a thread that shows its piped output prefixed (keeping its last lines)."""

    def __init__(self, process: Process, popen: subprocess.Popen, colour: int | None, logs: Path | None):
        self.process, self.popen = process, popen
        self.last_lines: collections.deque[str] = collections.deque(maxlen=15)
        self.reader = None
        if popen.stdout is not None:
            prefix = f"{process.name:>8} | "
            if colour is not None:
                prefix = f"\033[{colour}m{prefix}\033[0m"
            copy = open(logs / f"{process.name}.log", "w") if logs else None
            self.reader = threading.Thread(target=self._show, args=(popen.stdout.fileno(), prefix, copy), daemon=True)
            self.reader.start()

    def _show(self, pipe: int, prefix: str, copy) -> None:
        """Each line, prefixed; a progress bar (lines ended by \r) every PROGRESS_S at most."""
        shown_at, pending = 0.0, b""
        for chunk in iter(lambda: os.read(pipe, 65536), b""):
            pending += chunk
            *pieces, pending = re.split(rb"(\r\n|\n|\r)", pending)
            for text, end in zip(pieces[::2], pieces[1::2]):
                line = text.decode(errors="replace")
                if end == b"\r" and time.monotonic() - shown_at < PROGRESS_S or not line.strip():
                    continue
                shown_at = time.monotonic() if end == b"\r" else shown_at
                self.last_lines.append(line)
                sys.stdout.write(prefix + line + "\n")
                sys.stdout.flush()
                if copy:
                    copy.write(line + "\n")
                    copy.flush()
        if copy:
            copy.close()

    def tail(self) -> str:
        if self.reader is not None:
            self.reader.join(1)
            return "\n".join(self.last_lines)
        path = self.process.log
        if path is None or not path.exists():
            return "(above)"
        return "\n".join(path.read_text(errors="replace").splitlines()[-15:])


class Launcher:
    """Service processes started together, watched, and ended together."""

    def __init__(self, logs: Path | None = None, colour: bool | None = None, say_clean_ends: bool = True):
        """`say_clean_ends`: a line when a process ends with exit 0 (`spikinglab run` reports the run instead)."""
        self.children: dict[str, Child] = {}
        self.logs, self.say_clean_ends = logs, say_clean_ends
        if colour is None:
            colour = sys.stdout.isatty() and "NO_COLOR" not in os.environ
        self._colours = itertools.cycle(COLOURS) if colour else itertools.repeat(None)

    def start(self, process: Process) -> subprocess.Popen:
        if process.name in self.children:
            raise LaunchError(f"two processes named {process.name!r}")
        output = process.log or (None if process.raw else subprocess.PIPE)
        with ctrl_c_held():  # a process started is one watched, and stopped with the others
            popen = spawn(process.service, process.argv(), output)
            self.children[process.name] = Child(process, popen, next(self._colours), self.logs)
        return popen

    def watch(self, until: str | None = None, poll_s: float = 0.1, optional: tuple = ()) -> str | None:
        """Until `until` has ended (None: every process): a process that fails, or ends while
        `until` goes on (for longer than ENDING_S: `until` may be ending too), is noticed within
        `poll_s`; then a line saying which, and its last lines, are logged and returned. An
        `optional` process (a recorder) that fails is logged and the others go on."""
        ended_at: dict[str, float] = {}
        while True:
            for name, child in self.children.items():
                code = child.popen.poll()
                if code is None or name in ended_at and name in optional:
                    continue
                if name not in ended_at:
                    ended_at[name] = time.monotonic()
                    if code != 0 or self.say_clean_ends:
                        log.info("the %s ended (exit %s)", name, code)
                if name in optional:
                    if code != 0:
                        log.error(
                            "the %s stopped (exit %s); the others go on without it. Its last lines:\n%s",
                            name,
                            code,
                            child.tail(),
                        )
                    continue
                early = until is not None and name != until and self.running(until)
                if code != 0 or early and time.monotonic() - ended_at[name] > ENDING_S:
                    why = f"the {name} stopped (exit {code})" + (f" before the {until} ended" if early else "")
                    log.error("%s; stopping the others. Its last lines:\n%s", why, child.tail())
                    return why
            if (
                until is not None
                and not self.running(until)
                or until is None
                and not any(self.running(n) for n in self.children)
            ):
                return None
            time.sleep(poll_s)

    def running(self, name: str) -> bool:
        return self.children[name].popen.poll() is None

    def finish(self, timeout: float = FINISH_S) -> None:
        """Let every process end by itself (a brain saving, a recorder writing) within `timeout`;
        then stop the rest (a router, a fake brick), in ending order."""
        deadline = time.monotonic() + timeout
        for child in self.children.values():
            if child.process.service in ENDLESS:
                continue
            try:
                child.popen.wait(max(deadline - time.monotonic(), 0.1))
            except subprocess.TimeoutExpired:
                log.warning("the %s did not end within %.0f s; stopping it", child.process.name, timeout)
        for name in self.ending_order():
            self.stop(name)

    def stop(self, name: str, timeout: float = STOP_S) -> None:
        self.stop_in_order([name], timeout)

    def stop_in_order(self, names: list[str], timeout: float = STOP_S) -> None:
        """SIGTERM to each in turn, but to each run of processes of one service at once (a sharded
        brain's, a sharded world's): a process given `timeout` s to end, not one after the other."""
        for _, run in itertools.groupby(names, key=lambda name: self.children[name].process.service):
            together = list(run)
            for k in stop_together([self.children[name].popen for name in together], timeout):
                log.warning("the %s did not end within %.0f s of its SIGTERM; killed it", together[k], timeout)

    def ending_order(self) -> list[str]:
        """Start order (the world first writes what it has), but a router or a fake brick last:
        the others still need them to say goodbye. Processes of one service side by side."""
        first = {}  # each service where its first process starts
        for k, name in enumerate(self.children):
            first.setdefault(self.children[name].process.service, k)
        return sorted(
            self.children,
            key=lambda name: (
                self.children[name].process.service in ENDLESS,
                first[self.children[name].process.service],
            ),
        )

    def stop_all(self, timeout: float = 5.0) -> None:
        self.stop_in_order(self.ending_order(), timeout)
        for child in self.children.values():
            if child.reader is not None:
                child.reader.join(1)


def read_launch_file(path: Path) -> tuple[list[Process], str | None]:
    """The processes of a launch file, each checked by its service's parser, and its `until`."""
    try:
        data = tomllib.loads(path.read_text())
    except OSError as e:
        raise LaunchError(f"cannot read launch file {path}: {e.strerror}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise LaunchError(f"{path} is not valid TOML: {e}") from None
    settings = data.pop("launch", {})
    unknown = sorted(set(settings) - {"until"})
    if unknown:
        raise LaunchError(f"{path}, [launch]: unknown key(s) {', '.join(unknown)} (known: until)")
    processes, parsed = [], {}
    for name, table in data.items():
        if not isinstance(table, dict):
            raise LaunchError(f"{path}: {name!r} should be a table [{name}] of a process's options")
        if not re.fullmatch(r"\w[\w-]*", name):  # its log is <name>.log in the logs folder
            raise LaunchError(f"{path}: [{name!r}]: a process's name is letters, digits, _ and -")
        options = dict(table)
        process = Process(name, str(options.pop("service", name)), options)
        parsed[name] = process.check(f"{path}, [{name}]")
        processes.append(process)
    if not processes:
        raise LaunchError(f"{path} names no process: add a table such as [world]")
    check_worlds_params(path, processes, parsed)
    check_maps(path, processes, parsed)
    check_world_shards_agree(path, processes, parsed)
    check_brains_fit_worlds(path, processes, parsed)
    check_brains_weights(path, processes, parsed)
    until = settings.get("until")
    if until is not None and (not isinstance(until, str) or until not in data):
        raise LaunchError(f"{path}, [launch]: until = {until!r} is not one of its processes ({', '.join(data)})")
    return processes, until


def check_worlds_params(path: Path, processes: list[Process], parsed: dict[str, argparse.Namespace]) -> None:
    """A world's `params` file, read as the world reads it and checked to fit its agents: it would
    stop at its start with the others running."""
    for world in (p for p in processes if p.service == "world" and parsed[p.name].params is not None):
        args = parsed[world.name]
        try:
            file_for_agents(args.params, args.agents, f"agents = {args.agents}")
        except ValueError as e:
            raise LaunchError(f"{path}, [{world.name}]: {e}") from None


def check_maps(path: Path, processes: list[Process], parsed: dict[str, argparse.Namespace]) -> None:
    """A world's `map`, and a simulated EV3's floor (`sim_map`, its objects' size), read as they
    will be: the process would stop at its start with the others running."""
    from services.ev3_gateway.backends import sim_floor
    from services.world.world import map_world, params_for

    for process in processes:
        args = parsed[process.name]
        try:
            if process.service == "world" and args.map is not None:
                map_world(args.map, params_for(args.preset))
            elif process.service == "gateway" and args.backend == "sim":
                sim_floor(args.sim_patch_cm, args.sim_object_cm, args.sim_map)
        except (ValueError, OSError) as e:  # MapError is a ValueError
            raise LaunchError(f"{path}, [{process.name}]: {e}") from None


def check_world_shards_agree(path: Path, processes: list[Process], parsed: dict[str, argparse.Namespace]) -> None:
    """The world shards of a group in one file make one population: each shard once, and every one
    with the options of shard 1 (where the file holds it) that they must share (the shards would
    refuse to join, after the start; services/world/shards.py)."""
    from services.options import config_from
    from services.world.options import WorldOptions
    from services.world.shards import differences, terms

    taken: dict[tuple[str, int], str] = {}
    leads = {}
    worlds = [(p.name, parsed[p.name]) for p in processes if p.service == "world" and parsed[p.name].shard[1] > 1]
    for name, args in sorted(worlds, key=lambda world: world[1].shard):
        (i, n), where = args.shard, f"{path}, [{name}]"
        if (args.group, i) in taken:
            raise LaunchError(
                f'{where}: shard = "{i}/{n}" is also [{taken[args.group, i]}]\'s: each shard is one process'
            )
        taken[args.group, i] = name
        mine = terms(config_from(args, WorldOptions, whole=False), "", n, args.shards)
        if i == 1:
            leads[args.group] = mine
        elif args.group in leads:
            differ = differences(mine, leads[args.group])
            if differ:
                raise LaunchError(f"{where}: not of world shard 1's population: {'; '.join(differ)}")


def check_brains_fit_worlds(path: Path, processes: list[Process], parsed: dict[str, argparse.Namespace]) -> None:
    """What no one service's parser sees: a brain launched with a world it cannot serve (another group,
    shard count or number of agents in its parameter file) would refuse every message while the world
    waits. A file with no world (its brain joins a world elsewhere) is not checked."""
    worlds = {p.name: parsed[p.name] for p in processes if p.service == "world"}
    if not worlds:
        return
    shards_taken: dict[tuple[str, int], str] = {}
    for brain in (p for p in processes if p.service == "brain"):
        args, where = parsed[brain.name], f"{path}, [{brain.name}]"
        world_name = next((name for name, w in worlds.items() if w.group == args.group), None)
        if world_name is None:
            raise LaunchError(
                f"{where}: group {args.group!r} is no world's in this file (theirs: "
                f"{', '.join(sorted({w.group for w in worlds.values()}))}): the brain would wait for "
                f"sensors that never come"
            )
        world, (i, n) = worlds[world_name], args.shard
        if n != world.shards:
            given = f'shard = "{i}/{n}"' if "shard" in brain.options else f'no shard (so "{i}/{n}")'
            raise LaunchError(f"{where}: {given}, but [{world_name}] runs the brain as shards = {world.shards}")
        if args.world_shards != world.shard[1]:  # the brain would refuse the pieces of the others
            raise LaunchError(
                f"{where}: world_shards = {args.world_shards}, but [{world_name}] is one of {world.shard[1]} "
                f"world shards: set world_shards = {world.shard[1]}"
            )
        if (args.group, i) in shards_taken:
            raise LaunchError(f"{where}: shard {i}/{n} is also [{shards_taken[args.group, i]}]'s")
        shards_taken[args.group, i] = brain.name
        try:  # as `spikinglab run` checks its circuit
            check_sensors(load_circuit(args.circuit), SENSORS)
        except ValueError as e:
            raise LaunchError(f"{where}: {e}") from None
        if args.params is not None:
            try:
                file_for_agents(args.params, world.agents, f"agents of [{world_name}]")
            except ValueError as e:
                raise LaunchError(f"{where}: {e}") from None


def check_brains_weights(path: Path, processes: list[Process], parsed: dict[str, argparse.Namespace]) -> None:
    """A brain's `load`: a weights checkpoint of its circuit, or the brain would stop at its start
    with the others running."""
    for brain in (p for p in processes if p.service == "brain" and parsed[p.name].load is not None):
        args = parsed[brain.name]
        try:
            w_max = read_params(args.params).get("w_max") if args.params is not None else None
            load_weights(args.load, load_circuit(args.circuit), w_max=w_max)
        except ValueError as e:
            raise LaunchError(f"{path}, [{brain.name}]: {e}") from None


def shipped() -> dict[str, Path]:
    """The launch files shipped with spikinglab, by name."""
    folder = Path(str(resources.files("services") / "launch_files"))
    return {path.stem: path for path in sorted(folder.glob("*.toml"))}


def launch_file(text: str) -> Path:
    """A launch file's path, or the name of a shipped one (simulation, robot, ...)."""
    path = Path(text)
    if path.suffix == "" and not path.exists() and text in shipped():
        return shipped()[text]
    if not path.is_file():
        raise argparse.ArgumentTypeError(
            f"no launch file {text!r} (a .toml path, or one of the shipped: {', '.join(shipped())})"
        )
    return path


def parser() -> argparse.ArgumentParser:
    p = Parser(
        prog="spikinglab launch",
        description="Start the services a launch file names, show their logs, end them together (docs/launch.md).",
    )
    p.add_argument(
        "file", type=launch_file, nargs="?", help=f"a launch file (.toml), or a shipped one: {', '.join(shipped())}"
    )
    p.add_argument("--list", action="store_true", help="name the shipped launch files and where they are")
    p.add_argument("--logs", type=output_folder, help="also write each process's output to LOGS/<name>.log")
    p.add_argument("--no-colour", action="store_true", help="no colours in the prefixes")
    return p


def main(argv=None) -> int:
    logging.basicConfig(level=logging.INFO, format="launch: %(message)s", stream=sys.stderr)
    p = parser()
    args = p.parse_args(argv)
    if args.list and args.file is not None:
        p.error("argument --list: names the shipped launch files, and starts none: give no file with it")
    if args.list:
        files = shipped()
        width = max(map(len, files))
        for name, path in files.items():
            print(f"{name:{width}s}  {path}")
        return 0
    if args.file is None:
        p.error("which launch file? a .toml path, or one of the shipped: " + ", ".join(shipped()))
    try:
        processes, until = read_launch_file(args.file)
    except LaunchError as e:  # a usage error, named as every command names its own
        print(f"{p.prog}: {e}", file=sys.stderr)
        return 2
    if args.logs:
        args.logs.mkdir(parents=True, exist_ok=True)
    launcher = Launcher(logs=args.logs, colour=False if args.no_colour else None)
    signal.signal(signal.SIGTERM, signal.default_int_handler)  # SIGTERM ends the launch as Ctrl-C does
    try:
        try:
            for process in processes:
                launcher.start(process)
            log.info(
                "started %s%s",
                ", ".join(p.name for p in processes),
                f"; until the {until} ends" if until else f"; Ctrl-C ends {'them' if len(processes) > 1 else 'it'}",
            )
            failure = launcher.watch(until)
            if failure is None:
                launcher.finish()
            else:  # the others write what they have, as on Ctrl-C (a lead world shard waits for the rest)
                launcher.stop_all(timeout=STOP_S)
        except KeyboardInterrupt:
            order = launcher.ending_order()
            log.warning("interrupted: ending %s in order", ", ".join(order))
            launcher.stop_in_order(order)
            return 130
    except KeyboardInterrupt:
        return 130
    finally:
        launcher.stop_all()
    if failure:
        return 1
    log.info("all ended")
    return 0


if __name__ == "__main__":
    sys.exit(main())
