"""The docs say what the code does: each service README names every option of its service and no
option that is gone; every `spikinglab <command>` the docs name exists, with the options named
beside it; a default the docs state is the parser's; the schema version in docs/bus.md is the
code's; the files and links cited exist; the README's headline is what the default run computes."""

import argparse
import re
from functools import cache
from importlib import import_module
from pathlib import Path
from unittest import mock

import numpy as np
import pytest

from services.commands import BENCHMARKS, COMMANDS, SERVICES

ROOT = Path(__file__).resolve().parents[1]
README_OF = {
    "world": "world",
    "brain": "brain",
    "record": "recorder",
    "gateway": "ev3_gateway",
    "fake-brick": "ev3_gateway",
}
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), *sorted((ROOT / "services").glob("*/README.md"))]
SOURCES = [  # every file of the project that may cite another: docs, code, tests, circuits, scripts
    path
    for folder in ("services", "spikinglab", "tests", "examples", "scripts")
    for path in sorted((ROOT / folder).rglob("*"))
    if path.suffix in (".py", ".toml", ".sh", ".md") and "__pycache__" not in path.parts
]
HOME = {  # the commands a doc is about: an option it names without naming a command is one of theirs
    "README.md": ("run",),
    "docs/robot.md": ("gateway", "brain", "fake-brick"),
    "docs/recorder.md": ("record", "screenshot"),
    "docs/launch.md": ("launch",),
    "docs/security.md": ("certs", "router"),
    "docs/bus.md": ("world", "brain"),
    "docs/world.md": ("world",),
    "docs/results.md": ("run", "sweep"),
    **{
        f"services/{folder}/README.md": tuple(s for s, f in README_OF.items() if f == folder)
        for folder in README_OF.values()
    },
}
OPTION = r"--[a-z][\w-]*"
# a command, not a command's message ("spikinglab launch: ...")
COMMAND = re.compile(r"(?:^|(?<=[\s/(]))(?<!from )spikinglab +(bench +[a-z][\w-]*|[a-z][\w-]*)(?![\w:-])")
UNITS = {"ms": 1e-3, "s": 1.0}  # a time stated in the docs, to seconds


class _Parsed(Exception):
    """Carries the parser a command's main() built, before it parses anything."""


@cache
def parser_of(command: str) -> argparse.ArgumentParser:
    """The parser of `spikinglab <command>` ("bench engine" for a benchmark): its module's parser(),
    or the one its main() builds (caught as main parses ["--help"])."""
    words = command.split()
    module = import_module(BENCHMARKS[words[1]] if words[0] == "bench" else COMMANDS[command].module)
    if hasattr(module, "parser"):
        return module.parser()

    def caught(self, *args, **kwargs):
        raise _Parsed(self)

    with (
        mock.patch.object(argparse.ArgumentParser, "parse_args", caught),
        mock.patch.object(argparse.ArgumentParser, "parse_known_args", caught),
        pytest.raises(_Parsed) as parsed,
    ):
        module.main(["--help"])
    return parsed.value.args[0]


def actions(command: str) -> dict[str, argparse.Action]:
    """`--option` -> its action, for every option of the command but --help."""
    return {o: a for a in parser_of(command)._actions for o in a.option_strings if o.startswith("--") and o != "--help"}


def options(service: str) -> set[str]:
    return set(actions(service))


def known(command: str) -> bool:
    words = command.split()
    return words[1] in BENCHMARKS if words[0] == "bench" and len(words) > 1 else command in COMMANDS


def relative(doc: Path) -> str:
    return str(doc.relative_to(ROOT))


def fragments(text: str) -> list[str]:
    """The code of a markdown text: each line of a fenced block, and each inline `code` span (which
    may go on over a line break)."""
    found, prose, fenced = [], [], False
    for line in text.splitlines():
        if line.lstrip().startswith("```"):
            fenced = not fenced
        elif fenced:
            found.append(line.split(" #")[0])
        else:
            prose.append(line)
    return found + [" ".join(span.split()) for span in re.findall(r"`([^`]+)`", "\n".join(prose))]


def commands_named(text: str) -> list[tuple[str, list[str]]]:
    """Each `spikinglab <command>` in the text's code, with the options written after it (up to
    the next command, `&&`, `|` or `;`)."""
    named = []
    for fragment in fragments(text):
        for part in re.split(r"&&|\|\||[|;]", fragment):
            for match in COMMAND.finditer(part):
                rest = COMMAND.split(part[match.end() :])[0]
                named.append((re.sub(" +", " ", match.group(1)), re.findall(r"(?<![\w-])" + OPTION, rest)))
    return named


def option_lists(text: str) -> list[tuple[str, str]]:
    """A markdown list introduced by a line that names one command and ends with ':' (`spikinglab
    run` options: ...): that command, and the list's items."""
    lists, lines = [], text.splitlines()
    for i, line in enumerate(lines):
        if not line.rstrip().endswith(":") or i + 1 >= len(lines) or not lines[i + 1].startswith("- "):
            continue
        commands = {c for c, _ in commands_named(line)}
        if len(commands) != 1:
            continue
        items = []
        for item in lines[i + 1 :]:
            if not item.startswith(("- ", "  ")):
                break
            items.append(item)
        lists.append((commands.pop(), "\n".join(items)))
    return lists


def listed_options(items: str) -> list[str]:
    return re.findall(r"`(" + OPTION + ")", items)


@pytest.mark.parametrize("service", sorted(README_OF))
def test_service_readme_names_every_option(service):
    text = (ROOT / "services" / README_OF[service] / "README.md").read_text()
    missing = sorted(o for o in options(service) if not re.search(re.escape(o) + r"(?![\w-])", text))
    assert not missing, f"services/{README_OF[service]}/README.md does not name {missing}"


@pytest.mark.parametrize("folder", sorted(set(README_OF.values())))
def test_service_readme_names_no_option_that_is_gone(folder):
    known_options = set().union(*(options(s) for s, f in README_OF.items() if f == folder))
    named = set(re.findall(r"`(--[a-z][\w-]*)", (ROOT / "services" / folder / "README.md").read_text()))
    assert named - known_options == set()


def test_the_registry_has_a_parser_for_every_command():
    for command in [*COMMANDS, *(f"bench {b}" for b in BENCHMARKS)]:
        if command != "bench":
            assert parser_of(command).prog == f"spikinglab {command}"
    assert set(SERVICES) <= set(COMMANDS)


@pytest.mark.parametrize("doc", DOCS, ids=relative)
def test_every_command_named_exists_with_the_options_named_beside_it(doc):
    text = doc.read_text()
    named = commands_named(text) + [(c, listed_options(items)) for c, items in option_lists(text)]
    unknown = sorted({c for c, _ in named if not known(c)})
    assert not unknown, f"{relative(doc)} names commands that spikinglab has not: {unknown}"
    wrong = sorted(
        {f"spikinglab {c} {o}" for c, opts in named for o in opts if c != "bench" and o not in {*actions(c), "--help"}}
    )
    assert not wrong, f"{relative(doc)} names options that these commands do not have: {wrong}"


def test_the_command_checks_catch_what_is_gone():
    """The two checks above can fail: a command or option that is not there is found."""
    text = "`spikinglab fake-brik`, `spikinglab run --tick 5`\n```\nspikinglab bench engin  # x\n```\n"
    assert sorted(c for c, _ in commands_named(text) if not known(c)) == ["bench engin", "fake-brik"]
    ((command, items),) = option_lists("`spikinglab run` options:\n- `--ticks N`: ticks\n- `--tick`: gone\n\nafter\n")
    assert (command, listed_options(items)) == ("run", ["--ticks", "--tick"]) and "--tick" not in actions("run")


def stated_defaults(text: str) -> list[tuple[str, str, str | None, str]]:
    """Every default the text states for an option: (option, value, unit, the clause) for
    "`--option ...` (default 5 ms)" and for "5 ms (`--option`)"."""
    stated = []
    clauses = re.split(r"(?<=[.;])\s+(?=[A-Z(`])|\n(?=\s*[-|])|\s\|\s", text)  # sentences, list items, table cells
    number = r"\d(?:[\d,.]*\d)?"
    value = rf"({number}(?: {number})+|[\w.,:/+-]*\w)(?: (ms|s|cm|MB|ticks)\b)?"  # a list: numbers and spaces
    for clause in clauses:
        clause = " ".join(clause.split())
        for m in re.finditer(r"`(" + OPTION + r")[^`]*`(?:(?!`--).)*?(?<!by )(?<!'s )\bdefault:? `?" + value, clause):
            stated.append((m.group(1), m.group(2), m.group(3), clause))
        for m in re.finditer(
            r"(?<![\w.,])(\d[\d,]*(?:\.\d+)?) ?(ms|s|cm|MB)?\b \(`(" + OPTION + r")`(?=\)| on |,)", clause
        ):
            stated.append((m.group(3), m.group(1), m.group(2), clause))
    return stated


def same_value(stated: str, unit: str | None, option: str, default) -> bool:
    """Whether a value the docs state is the option's default, a time in the option's own unit (ms
    for an option named -ms, else seconds); a list, its values one by one."""
    if default is None or isinstance(default, bool) or default == []:
        return True  # the parser says nothing to compare with: the code decides (a flag, a default made later)
    if isinstance(default, (tuple, list)):
        values = stated.split(" ") if " " in stated else stated.split(",")
        return len(values) == len(default) and all(same_value(v, unit, option, d) for v, d in zip(values, default))
    number = re.fullmatch(r"-?\d[\d,]*(?:\.\d+)?", stated)
    if number is None:
        return str(default) == stated
    if not isinstance(default, (int, float, str)):
        return False
    value = float(stated.replace(",", ""))
    if unit in UNITS:
        value *= UNITS[unit] / UNITS["ms" if option.endswith("-ms") else "s"]
    try:
        return abs(value - float(default)) <= 1e-9 * max(1.0, abs(value))
    except ValueError:
        return False


def candidates(option: str, clause: str, doc: str) -> list[str]:
    """The commands an option named in a doc's clause belongs to: those the clause names that have
    it, else the doc's own, else every command that has it."""
    everyone = [c for c in [*COMMANDS, *(f"bench {b}" for b in BENCHMARKS)] if c != "bench" and option in actions(c)]
    for commands in ([c for c, _ in commands_named(clause)], HOME.get(doc, ())):
        having = [c for c in commands if c in everyone]
        if having:
            return having
    return everyone


@pytest.mark.parametrize("doc", DOCS, ids=relative)
def test_every_default_stated_is_the_parsers(doc):
    """An option list's defaults are its command's; elsewhere an option's command is the one the
    sentence names, or the doc's own."""
    text, stated = doc.read_text(), []
    for command, items in option_lists(text):
        stated += [(*default, [command]) for default in stated_defaults(items)]
        text = text.replace(items, "")
    stated += [(*default, None) for default in stated_defaults(text)]
    wrong = []
    for option, value, unit, clause, listed in stated:
        commands = [c for c in listed if option in actions(c)] if listed else candidates(option, clause, relative(doc))
        defaults = [actions(c)[option].default for c in commands]
        if commands and not any(same_value(value, unit, option, d) for d in defaults):
            wrong.append(f"{option} {value}{' ' + unit if unit else ''} ({', '.join(commands)}: default {defaults})")
    assert not wrong, f"{relative(doc)} states defaults the parsers do not have: {wrong}"


def test_the_default_check_catches_a_wrong_default():
    """250 ms where the gateway's --motor-timeout is 0.2 s, 500 ms where --move-ms is 500: both forms."""
    text = "- stop after 250 ms (`--motor-timeout`); walk 500 ms (`--move-ms`)\n- `--ticks N` (default 40,000)"
    found = [(o, v, u) for o, v, u, _ in stated_defaults(text)]
    assert found == [("--motor-timeout", "250", "ms"), ("--move-ms", "500", "ms"), ("--ticks", "40,000", None)]
    gateway = actions("gateway")
    assert not same_value("250", "ms", "--motor-timeout", gateway["--motor-timeout"].default)
    assert same_value("0.2", "s", "--motor-timeout", gateway["--motor-timeout"].default)
    assert same_value("500", "ms", "--move-ms", gateway["--move-ms"].default)
    assert not same_value("40,000", None, "--ticks", actions("run")["--ticks"].default)
    assert same_value("0.01 0.02 0.03 0.04", None, "--a-plus", [0.01, 0.02, 0.03, 0.04])
    assert not same_value("0.01 0.02", None, "--a-plus", [0.01, 0.02, 0.03, 0.04])


def bus_keys() -> set[str]:
    """Every key expression of services/bus/keys.py below `spikinglab/<group>/`, as the docs write
    them (<i>of<n> for a shard, <service> or a role for a liveliness token)."""
    from services.bus import keys
    from services.certs import PUTS

    group, shard = "<group>", (2, 3)
    made = [keys.sensors(group), keys.sensors(group, shard), keys.motor(group), keys.control(group)]
    made += [keys.brain_state(group), keys.world_state(group), keys.world_map(group), keys.state(group)]
    made += [keys.world_run(group)]
    made += [keys.alive(group, s) for s in ("*", "<service>", *PUTS, keys.brain_service(shard))]
    prefix, shard_name = f"{keys.PREFIX}/{group}/", keys.shard_name(shard)
    return {key.removeprefix(prefix).replace(shard_name, "<i>of<n>") for key in made} | {""}


@pytest.mark.parametrize("doc", DOCS, ids=relative)
def test_every_key_named_is_a_key_of_the_bus(doc):
    named = re.findall(r"`(?:spikinglab/<group>|\.\.\.)/([^`\s]*)`", doc.read_text())
    keys = bus_keys()
    unknown = {k for k in named if k not in keys and not (k.endswith("/") and any(b.startswith(k) for b in keys))}
    assert not unknown, f"{relative(doc)} names keys the bus has not: {unknown}"


KEY_FUNCTION = {  # a key a service README says its service reads -> the function of services/bus/keys.py
    "sensors": "sensors",
    "sensors/<i>of<n>": "sensors",
    "motor": "motor",
    "control": "control",
    "state/brain": "brain_state",
    "state/world": "world_state",
    "state/map": "world_map",
    "world/run": "world_run",
    "state/**": "state",
}


@pytest.mark.parametrize("folder", sorted(set(README_OF.values())))
def test_a_service_readme_says_what_its_service_reads(folder):
    """Each key the README's "reads" names is one its service's code asks the bus for (the
    liveliness tokens aside): a recorder that reads `state/**` only does not read "everything"."""
    text = " ".join((ROOT / "services" / folder / "README.md").read_text().split())
    reads = re.search(r"Service: reads (.*?)[;:] writes", text)
    assert reads, f"services/{folder}/README.md has no 'Service: reads ...; writes ...'"
    named = [k for k in re.findall(r"`(?:spikinglab/<group>|\.\.\.)/([^`\s]*)`", reads.group(1)) if "alive" not in k]
    code = "".join(p.read_text() for p in (ROOT / "services" / folder).glob("*.py"))
    unused = [k for k in named if f"keys.{KEY_FUNCTION.get(k, '?')}(" not in code]
    assert named and not unused, f"services/{folder}/README.md says it reads {unused or 'no key'}"


def test_docs_bus_states_the_schema_version_of_the_code():
    from services.bus.schemas import VERSION

    stated = re.findall(r"schema `version` \((\d+)\)", (ROOT / "docs" / "bus.md").read_text())
    assert stated == [str(VERSION)], f"docs/bus.md says schema version {stated}, the code speaks {VERSION}"


def test_docs_tick_states_the_engines_history_shape():
    from services.brain.engine import Engine
    from spikinglab import load_circuit

    engine = Engine(load_circuit("insect"), agents=3)
    stated = re.findall(r"agent-major, `\[A, neurons, (\d+)\]`", (ROOT / "docs" / "tick.md").read_text())
    assert engine.state.hist.shape[:2] == (3, engine.n_neurons)
    assert stated == [str(engine.state.hist.shape[2])], f"docs/tick.md: history [A, neurons, {stated}]"


@pytest.mark.parametrize("doc", DOCS, ids=relative)
def test_tables_are_not_broken_by_a_paragraph(doc):
    """A table row after prose renders as text: each table's rows are consecutive lines."""
    lines = doc.read_text().splitlines()
    for i, line in enumerate(lines):
        if line.startswith("|") and i > 0 and lines[i - 1].strip() and not lines[i - 1].startswith("|"):
            assert i + 1 < len(lines) and re.fullmatch(r"\|[-| :]+\|", lines[i + 1]), (
                f"{relative(doc)}:{i + 1}: a table row that follows prose: {line[:60]}"
            )


def test_docs_cite_only_files_that_exist():
    cited = {}
    for source in DOCS + SOURCES:
        for path in re.findall(
            r"\b((?:services|spikinglab|docs|tests|examples|scripts)/[\w./-]*\w(?:\.\w+|/(?![\w*{<])))",
            source.read_text(),
        ):
            if not path.endswith("circuits/mine.toml"):  # docs/circuits.md: a user's own file in its error examples
                cited.setdefault(path, relative(source))
    missing = {path: doc for path, doc in cited.items() if not (ROOT / path).exists()}
    assert len(cited) > 20 and not missing, f"files cited but not in the repository: {missing}"


def test_docs_cite_only_tests_that_exist():
    """A test cited by its file and name (path::name): the file defines it."""
    cited = {m for doc in DOCS for m in re.findall(r"\b(tests/[\w/]+\.py)::(\w+)", doc.read_text())}
    missing = [f"{f}::{t}" for f, t in cited if not re.search(rf"^def {t}\(", (ROOT / f).read_text(), re.M)]
    assert cited and not missing, f"tests cited but not defined: {missing}"


def test_docs_and_code_cite_only_top_level_docs_that_exist():
    """A document named by its bare file name (README.md) is in the repository."""
    present = {p.name for p in ROOT.rglob("*.md") if ".venv" not in p.parts}
    cited = {}
    for source in DOCS + SOURCES:
        for name in re.findall(r"(?<![\w/.-])([A-Z][A-Z_]*\.md)\b", source.read_text()):
            cited.setdefault(name, relative(source))
    missing = {name: source for name, source in cited.items() if name not in present}
    assert "README.md" in cited and not missing, f"documents cited but not in the repository: {missing}"


def slug(heading: str) -> str:
    """GitHub's anchor of a markdown heading."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def test_links_between_docs_lead_somewhere():
    """[text](path) and [text](path#anchor): the file exists, and the anchor is one of its headings."""
    broken = []
    for doc in DOCS:
        for target in re.findall(r"\]\(([^)\s]+)\)", doc.read_text()):
            if re.match(r"[a-z]+:", target):
                continue
            path, _, anchor = target.partition("#")
            file = (doc.parent / path).resolve() if path else doc
            headings = (
                re.findall(r"^#+ (.+)$", file.read_text(), re.M) if file.suffix == ".md" and file.exists() else []
            )
            if not file.exists() or (anchor and anchor not in map(slug, headings)):
                broken.append(f"{relative(doc)}: {target}")
    assert not broken, broken


def test_readme_headline_is_what_the_default_run_computes():
    """The README's figures for `spikinglab run` (collisions in the first and the last quarter, the
    learning time, the weights of the black smell), computed as the run computes them: the default
    world and circuit in one process, which is the run of processes bit for bit
    (tests/test_closed_loop.py)."""
    from services.learning import quarter_collisions
    from spikinglab import World, brain_for, closed_loop, load_circuit, params_for

    text = " ".join((ROOT / "README.md").read_text().split())
    said = re.search(
        r"collisions fall from ([\d,]+) in the first quarter to ([\d,]+) in the last, its learning time "
        r"is tick ([\d,]+) .*?BLACK->PAIN rises from ([\d.]+) to ([\d.]+) while "
        r"BLACK->REWARD falls to ([\d.]+)",
        text,
    )
    assert said, "README.md no longer states the headline in the words this test reads"
    first, last, learned, pain_from, pain_to, reward_to = (float(x.replace(",", "")) for x in said.groups())
    run = import_module("services.run").parser().parse_args([])
    world = World(params_for(run.preset, learned_after=run.learned_after), agents=run.agents, seed=run.seed)
    circuit = load_circuit(run.circuit)
    brain = brain_for(world, circuit, semantics=run.semantics, order=run.order)
    pain, reward = circuit.synapse_index("BLACK", "PAIN"), circuit.synapse_index("BLACK", "REWARD")
    initial = brain.engine.get_weights()[0]
    closed_loop(world, brain, run.ticks)
    quarters = quarter_collisions(np.array(world.metrics.bins).T)
    final = brain.engine.get_weights()[0]
    assert (quarters[0][0], quarters[1][0], world.metrics.learned_at[0]) == (first, last, learned)
    assert (initial[pain], final[pain], final[reward]) == pytest.approx((pain_from, pain_to, reward_to), abs=0.005)
