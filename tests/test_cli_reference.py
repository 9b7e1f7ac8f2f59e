"""docs/cli-reference.md: generated from the `fishfmu` command's own help, current, and covering every command."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from fishfmu.cli.reference import COMMAND, cli_reference, commands, help_text

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def reference() -> str:
    return cli_reference()


def section(reference: str, command: str) -> str:
    """The text under ``## fishfmu COMMAND`` up to the next heading."""
    m = re.search(rf"^## fishfmu {re.escape(command)}\n(.*?)(?=^## |\Z)", reference, re.M | re.S)
    assert m, f"no section for fishfmu {command}"
    return m.group(1)


def test_committed_reference_is_current(reference: str) -> None:
    assert (ROOT / "docs" / "cli-reference.md").read_text(encoding="utf-8") == reference, (
        f"docs/cli-reference.md is out of date with the command line; regenerate it: {COMMAND}")


def test_every_command_and_subcommand_has_its_section(reference: str) -> None:
    listed = {" ".join(words) for words in commands()}
    # worked out by hand from fishfmu/cli/__init__.py and bench.py: a walk that missed the bench group's
    # subcommands, or a command, fails here
    assert {"run", "check", "serve", "export-fmu", "build-fmus", "sweep", "replay", "compare", "calibrate",
            "diagnose", "bench", "bench pile", "bench fmu-worker", "bench serve", "bench sweep", "bench diagnose",
            "bench scenario"} <= listed
    assert set(re.findall(r"^## fishfmu (.+)$", reference, re.M)) == listed
    for command in listed:  # each in the table of contents, linked to its section
        assert f"| [`fishfmu {command}`](#fishfmu-{command.replace(' ', '-')}) |" in reference


def test_spot_checks_worked_out_by_hand(reference: str) -> None:
    run = section(reference, "run")
    assert "Usage: fishfmu run [OPTIONS]" in run
    assert re.search(r"--seeds <int range>\s+Run this many seeds", run)
    assert "[default: 1; x>=1]" in run  # typer.Option(1, "--seeds", min=1)
    assert "--report / --no-report" in run
    sweep = section(reference, "sweep")
    assert re.search(r"--out <path>\s+Sweep folder; the same command on the same folder resumes\.\s+\[required\]", sweep)
    pile = section(reference, "bench pile")
    assert "Usage: fishfmu bench pile [OPTIONS]" in pile and "[default: 18,50,100,200]" in pile
    assert "--threads-per-worker" in sweep and "--threads-per-worker" not in run
    assert "pile" in section(reference, "bench")  # the group's own help lists its subcommands


def test_the_page_does_not_depend_on_the_terminal(monkeypatch: pytest.MonkeyPatch, reference: str) -> None:
    monkeypatch.setenv("COLUMNS", "40")
    assert help_text(("run",)) in reference
    assert cli_reference() == reference
    assert max(len(line) for line in help_text(("serve",)).splitlines()) <= 100
