"""The README and docs/: every relative link and anchor leads somewhere, every `fishfmu` command and option they
show exists, and the README stays an entry point (short, the two set-up commands CI and users run)."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest
import typer

from fishfmu.cli import app

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
README_MAX_LINES = 250
SETUP = ["python3.11 -m venv .venv && .venv/bin/pip install -c constraints.txt -e '.[test]' && "
         ".venv/bin/fishfmu run scenarios/paper_test.toml",
         ".venv/bin/python -m pytest"]

FENCE = re.compile(r"^```([\w-]*)\n(.*?)^```", re.M | re.S)
INLINE_CODE = re.compile(r"`([^`]+)`")
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")
SHELL = {"", "sh", "bash", "shell", "console"}  # fenced blocks holding commands


def _page_id(path: Path) -> str:
    return str(path.relative_to(ROOT))


def prose(text: str) -> str:
    """The page without its code: fenced blocks and inline code spans (a link or heading there is not one)."""
    return INLINE_CODE.sub("", FENCE.sub("", text))


def slug(heading: str) -> str:
    """The anchor GitHub gives a heading: its text in lower case, punctuation dropped, spaces as hyphens."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link's text
    text = re.sub(r"[^\w\- ]", "", text.replace("`", "").lower())
    return text.replace(" ", "-")


def anchors(text: str) -> set[str]:
    found: set[str] = set()
    for heading in re.findall(r"^#{1,6} +(.+?) *#*$", FENCE.sub("", text), re.M):
        base = slug(heading)
        name, n = base, 0
        while name in found:  # GitHub numbers a repeated heading: x, x-1, x-2
            n += 1
            name = f"{base}-{n}"
        found.add(name)
    return found


def test_slug_worked_out_by_hand() -> None:
    assert slug("The plant as an FMU: `fishfmu export-fmu`") == "the-plant-as-an-fmu-fishfmu-export-fmu"
    assert slug("The paper's test as a study") == "the-papers-test-as-a-study"
    assert slug("Sweeps and Monte-Carlo KPIs") == "sweeps-and-monte-carlo-kpis"
    assert anchors("# A\n\n```sh\n# not a heading\n```\n## A\n") == {"a", "a-1"}


@pytest.mark.parametrize("page", PAGES, ids=_page_id)
def test_every_relative_link_and_anchor_leads_somewhere(page: Path) -> None:
    text = page.read_text(encoding="utf-8")
    broken = []
    for target in LINK.findall(prose(text)):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):  # https:, mailto:: not checked offline
            continue
        path, _, anchor = target.partition("#")
        file = (page.parent / path).resolve() if path else page
        if not file.exists():
            broken.append(f"{target}: no {path}")
        elif anchor and file.suffix == ".md" and anchor not in anchors(file.read_text(encoding="utf-8")):
            broken.append(f"{target}: no heading #{anchor} in {path or page.name}")
    assert not broken, f"{_page_id(page)}: broken links: {broken}"


def _command_options() -> dict[tuple[str, ...], set[str]]:
    """Every command as its words after ``fishfmu`` -> the options it takes (``--help`` included)."""
    out: dict[tuple[str, ...], set[str]] = {}

    def walk(group, path: tuple[str, ...]) -> None:  # noqa: ANN001 (typer's group)
        for name, command in group.commands.items():
            out[path + (name,)] = {o for p in command.params for o in (*p.opts, *p.secondary_opts)} | {"--help"}
            if hasattr(command, "commands"):
                walk(command, path + (name,))

    walk(typer.main.get_command(app), ())
    return out


def shown_commands(text: str) -> list[str]:
    """Each `fishfmu ...` command line a page shows: lines of its shell blocks (a trailing backslash continues
    a line) and inline code, split at ``&&``, ``;`` and ``|``, comments dropped; only those that start with
    ``fishfmu`` (or ``.../bin/fishfmu``)."""
    pieces = [block for lang, block in FENCE.findall(text) if lang in SHELL]
    pieces = [line for block in pieces for line in block.replace("\\\n", " ").splitlines()]
    pieces += [" ".join(span.split()) for span in INLINE_CODE.findall(FENCE.sub("", text))]
    out = []
    for piece in pieces:
        for part in re.split(r"&&|;|\|(?!\|)", re.sub(r"(^|\s)#.*$", "", piece)):
            part = " ".join(part.split())
            if re.match(r"^(\S*/)?fishfmu(\s|$)", part):
                out.append(re.sub(r"^\S*/fishfmu", "fishfmu", part))
    return out


@pytest.mark.parametrize("page", [p for p in PAGES if p.name != "cli-reference.md"], ids=_page_id)
def test_every_command_and_option_shown_exists(page: Path) -> None:
    known = _command_options()
    wrong = []
    for line in shown_commands(page.read_text(encoding="utf-8")):
        words = line.split()[1:]
        if not words or not re.fullmatch(r"[a-z][a-z-]*", words[0]):  # `fishfmu`, `fishfmu COMMAND --help`
            continue
        command = (words[0],)
        if command not in known:
            wrong.append(f"{line}: no command '{words[0]}'")
            continue
        is_group = any(len(k) == 2 and k[0] == words[0] for k in known)
        if is_group and len(words) > 1 and re.fullmatch(r"[a-z][a-z-]*", words[1]):  # `fishfmu bench pile ...`
            if command + (words[1],) not in known:
                wrong.append(f"{line}: no command '{words[0]} {words[1]}'")
                continue
            command += (words[1],)
        for option in re.findall(r"(?<![\w-])--[a-z][a-z-]*", line):
            if option not in known[command]:
                wrong.append(f"{line}: 'fishfmu {' '.join(command)}' has no option {option}")
    assert not wrong, f"{_page_id(page)}: " + "; ".join(wrong)


def test_shown_commands_worked_out_by_hand() -> None:
    text = ("Run `fishfmu run scenarios/x.toml --seeds 3` or `fishfmu/cli` or `commands.run`.\n\n"
            "```sh\npython3.11 -m venv .venv && .venv/bin/fishfmu check s.toml --json   # a comment --nope\n"
            "fishfmu sweep s.toml --out o \\\n    --param a=1,2\n```\n\n```text\nfishfmu manifest\n```\n")
    assert shown_commands(text) == ["fishfmu check s.toml --json", "fishfmu sweep s.toml --out o --param a=1,2",
                                    "fishfmu run scenarios/x.toml --seeds 3"]


def test_readme_is_an_entry_point() -> None:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) <= README_MAX_LINES, "the README is the entry point; reference goes to docs/"
    setup = re.search(r"^## Set-up.*?^```sh\n(.*?)^```", text, re.M | re.S)
    assert setup, "the README's set-up has its two commands in a ```sh block"
    assert setup.group(1).splitlines() == SETUP  # what .ci/run and users run, exactly
    assert all(shlex.split(command) for command in SETUP)
    # the layout near the top: before the set-up, naming each top-level folder
    layout = text.index("## Layout")
    assert layout < text.index("## Set-up")
    for folder in ("plant/", "fishfmu/", "scenarios/", "tests/", "docs/"):
        assert re.search(rf"^{re.escape(folder)}", text[layout:], re.M), folder
