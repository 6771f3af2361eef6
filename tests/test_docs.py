"""The docs say what the code does: each service README names every option of its service and no
option that is gone, and the docs cite only files that exist in the repository."""

import re
from importlib import import_module
from pathlib import Path

import pytest

from services.commands import SERVICES

ROOT = Path(__file__).resolve().parents[1]
README_OF = {
    "world": "world",
    "brain": "brain",
    "record": "recorder",
    "gateway": "ev3_gateway",
    "fake-brick": "ev3_gateway",
}
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), *sorted((ROOT / "services").glob("*/README.md"))]


def options(service: str) -> set[str]:
    parser = import_module(SERVICES[service]).parser()
    return {o for action in parser._actions for o in action.option_strings if o.startswith("--")} - {"--help"}


@pytest.mark.parametrize("service", sorted(README_OF))
def test_service_readme_names_every_option(service):
    text = (ROOT / "services" / README_OF[service] / "README.md").read_text()
    missing = sorted(o for o in options(service) if not re.search(re.escape(o) + r"(?![\w-])", text))
    assert not missing, f"services/{README_OF[service]}/README.md does not name {missing}"


@pytest.mark.parametrize("folder", sorted(set(README_OF.values())))
def test_service_readme_names_no_option_that_is_gone(folder):
    known = set().union(*(options(s) for s, f in README_OF.items() if f == folder))
    named = set(re.findall(r"`(--[a-z][\w-]*)", (ROOT / "services" / folder / "README.md").read_text()))
    assert named - known == set()


def test_docs_cite_only_files_that_exist():
    cited = {}
    for doc in DOCS:
        for path in re.findall(
            r"\b((?:services|spikinglab|docs|tests|examples|scripts)/[\w./-]*\w(?:\.\w+|/(?![\w*{<])))", doc.read_text()
        ):
            if not path.endswith("circuits/mine.toml"):  # docs/circuits.md: a user's own file in its error examples
                cited.setdefault(path, doc.relative_to(ROOT))
    missing = {path: str(doc) for path, doc in cited.items() if not (ROOT / path).exists()}
    assert len(cited) > 20 and not missing
