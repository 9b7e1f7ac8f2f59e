"""The command-line reference, generated from the ``fishfmu`` command's own help: docs/cli-reference.md.

One source of truth, as :mod:`fishfmu.scenario.reference` is for scenario keys: every command and
subcommand of the typer app is asked for its ``--help`` (the text a user sees), at a fixed width so
that the page does not depend on the terminal that made it. A command, option or help text added to
``fishfmu/cli`` reaches the page when it is regenerated; tests/test_cli_reference.py fails while the
committed page is out of date::

    python -m fishfmu.cli.reference --write

Without ``--write`` the Markdown goes to standard output.
"""

from __future__ import annotations

import sys
from pathlib import Path

import typer
from typer.testing import CliRunner

from fishfmu.cli import app
from fishfmu.terminal import generated_page

DOC_PATH = Path(__file__).resolve().parents[2] / "docs" / "cli-reference.md"
COMMAND = "python -m fishfmu.cli.reference --write"
HELP_WIDTH = 100  # columns of the help text; fixed, so that COLUMNS or the terminal do not change the page


def commands() -> list[tuple[str, ...]]:
    """Every command as its words after ``fishfmu``, in the order the app declares them: ``("run",)``,
    ``("bench", "pile")``; a group is listed before its subcommands."""
    out: list[tuple[str, ...]] = []

    def walk(group, path: tuple[str, ...]) -> None:  # noqa: ANN001 (typer's group; its click is typer's own copy)
        for name, command in group.commands.items():
            if command.hidden:
                continue
            out.append(path + (name,))
            if hasattr(command, "commands"):  # a group: bench
                walk(command, path + (name,))

    walk(typer.main.get_command(app), ())
    return out


def help_text(words: tuple[str, ...] = ()) -> str:
    """What ``fishfmu WORDS --help`` prints, at :data:`HELP_WIDTH` columns."""
    result = CliRunner().invoke(app, [*words, "--help"], prog_name="fishfmu", terminal_width=HELP_WIDTH,
                                max_content_width=HELP_WIDTH)
    if result.exit_code != 0:  # a command whose help cannot be shown is a bug in the app, not in the page
        raise RuntimeError(f"fishfmu {' '.join(words)} --help exited {result.exit_code}: {result.output}")
    return "\n".join(line.rstrip() for line in result.output.strip("\n").splitlines())


def summary(words: tuple[str, ...]) -> str:
    """The command's help paragraph on one line (its docstring), for the table of contents."""
    command = typer.main.get_command(app)
    for word in words:
        command = command.commands[word]
    return " ".join((command.help or "").split()).replace("|", "\\|")


def anchor(words: tuple[str, ...]) -> str:
    """The anchor GitHub gives the heading ``fishfmu WORDS`` (lower case, spaces as hyphens)."""
    return "fishfmu-" + "-".join(words)


def cli_reference() -> str:
    """The whole reference as Markdown."""
    listed = commands()
    lines = [
        "# Command-line reference",
        "",
        f"*Generated from the `fishfmu` command's own `--help` by `{COMMAND}`; do not edit by hand.*",
        "",
        "Every command and option, as `fishfmu COMMAND --help` prints it. Exit codes, errors and what a "
        "command promises about your files: [guarantees.md](guarantees.md); the keys `--set` takes: "
        "[scenario-reference.md](scenario-reference.md); what the commands are for, with examples: "
        "[scenarios.md](scenarios.md) and the pages the [README](../README.md) links.",
        "",
        "| command | what it does |",
        "| --- | --- |",
    ]
    lines += [f"| [`fishfmu {' '.join(w)}`](#{anchor(w)}) | {summary(w)} |" for w in listed]
    lines += ["", "## fishfmu", "", "```text", help_text(), "```", ""]
    for words in listed:
        lines += [f"## fishfmu {' '.join(words)}", "", "```text", help_text(words), "```", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    return generated_page(cli_reference(), DOC_PATH, COMMAND, sys.argv[1:] if argv is None else argv)


if __name__ == "__main__":
    raise SystemExit(main())
