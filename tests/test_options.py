"""services.options.Parser: a value that begins with '-', which argparse takes for an option; and a
launch file's values, which go to a service's parser as --option=value."""

import pytest

from services.launch import Process
from services.options import Parser


def parser() -> Parser:
    p = Parser(prog="p")
    p.add_argument("--shard")
    p.add_argument("--name")
    p.add_argument("rest", nargs="*")
    return p


@pytest.mark.parametrize(
    "args, name, shard, rest",
    [
        (["--shard", "-1"], None, "-1", []),  # a negative number
        (["--name", "-my log"], "-my log", None, []),  # with a space: a value to argparse
        (["--name", "-"], "-", None, []),  # standard input, say
        (["--shard=-1/2"], None, "-1/2", []),
        (["--", "--name", "-x"], None, None, ["--name", "-x"]),  # after --: not options
    ],
)
def test_what_argparse_takes_as_a_value_is_left_to_it(args, name, shard, rest):
    parsed = parser().parse_args(args)
    assert (parsed.name, parsed.shard, parsed.rest) == (name, shard, rest)


@pytest.mark.parametrize(
    "args, said",
    [
        (["--shard", "-1/2"], "argument --shard: its value '-1/2' begins with '-', so write --shard=-1/2"),
        (["--shard", "--nmae"], "argument --shard: expected one argument"),  # an option: argparse's own word
    ],
)
def test_a_value_argparse_would_take_for_an_option_is_refused_saying_how_to_give_it(args, said, capsys):
    with pytest.raises(SystemExit) as ended:
        parser().parse_args(args)
    assert ended.value.code == 2 and capsys.readouterr().err == f"p: {said} (see p --help)\n"


def test_a_launch_files_negative_value_reaches_the_service():
    """It went as two arguments, `--a-plus -1e-05`, and argparse said "expected one argument"."""
    assert Process("brain", "brain", {"a_plus": -1e-05}).check().a_plus == -1e-05


@pytest.mark.parametrize("command", [["certs", ""], ["launch", "simulation", "--logs", ""], ["record", "--out", ""]])
def test_an_empty_name_is_no_folder_or_file_to_write_to(command, tmp_path, monkeypatch, capsys):
    """Not the current folder unasked: `certs ""` wrote its keys there and made it private."""
    from spikinglab import cli

    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as ended:
        cli.main(command)
    assert ended.value.code == 2 and "got an empty" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())
