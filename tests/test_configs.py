"""Each service's typed config against its parser: every option has its field and every field its
option (services.options.config_from refuses a config out of step, at the service's start), with
values of the fields' types."""

import argparse
import dataclasses
from pathlib import Path

import pytest

from services.brain import service as brain
from services.ev3_gateway import service as gateway
from services.options import config_from, option_names
from services.recorder import service as recorder
from services.world import service as world

SERVICES = {
    "brain": (
        brain.parser,
        brain.BrainConfig,
        ["--shard", "2/3", "--world-shards", "2", "--params", "p.csv", "--a-plus", "0.03"],
    ),
    "gateway": (gateway.parser, gateway.GatewayConfig, ["--backend", "sim", "--sim-map", "m.txt"]),
    "recorder": (recorder.parser, recorder.RecorderConfig, ["--detail", "0,3", "--viewer", "rerun+http://h:1/proxy"]),
    "world": (
        world.parser,
        world.WorldConfig,
        ["--map", "m.txt", "--agents", "2", "--shards", "2", "--checkpoint", "c", "--out", "o"],
    ),
}


def options_of(parser: argparse.ArgumentParser) -> set[str]:
    return set(vars(parser.parse_args([])))  # every option, with its default


@pytest.mark.parametrize("service", SERVICES)
def test_every_option_has_its_field_and_every_field_its_option(service):
    parser, config, argv = SERVICES[service]
    assert option_names(config) == options_of(parser())
    for given in ([], argv):
        made = config_from(parser().parse_args(given), config)
        assert dataclasses.is_dataclass(made) and type(made) is config


@pytest.mark.parametrize("service", SERVICES)
def test_a_config_out_of_step_with_its_parser_is_refused(service):
    parser, config, _ = SERVICES[service]
    more = parser()
    more.add_argument("--undeclared-option")
    with pytest.raises(TypeError, match="no field for the option.s. undeclared_option"):
        config_from(more.parse_args([]), config)
    fewer = argparse.Namespace(**{k: v for k, v in vars(parser().parse_args([])).items() if k != "group"})
    with pytest.raises(TypeError, match=r"BusConfig.group has no option"):
        config_from(fewer, config)
    assert config_from(more.parse_args([]), config, whole=False)  # a launcher's options hold a config's and more


def test_a_value_not_of_its_field_type_is_refused():
    @dataclasses.dataclass(frozen=True)
    class Config:
        ticks: int
        out: Path | None
        rate: float

    assert config_from(argparse.Namespace(ticks=3, out=None, rate=1), Config) == Config(3, None, 1)
    with pytest.raises(TypeError, match=r"Config.ticks is <class 'int'>, the option gives '3'"):
        config_from(argparse.Namespace(ticks="3", out=None, rate=1.0), Config)
    with pytest.raises(TypeError, match=r"Config.out is pathlib.Path \| None, the option gives 'x'"):
        config_from(argparse.Namespace(ticks=3, out="x", rate=1.0), Config)
