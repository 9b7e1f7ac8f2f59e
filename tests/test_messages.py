"""What the command prints is the text it means: no markup, no emoji codes, one line per error.

The terminal library would read ``[expect]`` as a style tag and ``:fish:`` as an emoji code; paths,
scenario names and FMU messages are the user's text and must come out literally.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).parents[1]


def fishfmu(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "COLUMNS": "200"}
    return subprocess.run([sys.executable, "-m", "fishfmu.cli", *args], cwd=cwd, capture_output=True, text=True,
                          env=env, timeout=120)


def test_paths_with_emoji_codes_and_brackets_are_printed_literally(tmp_path: Path):
    folder = tmp_path / "a:fish:b" / "[bold]x[/]"
    folder.mkdir(parents=True)
    scenario = folder / "s:smile:.toml"
    scenario.write_text('[run]\nname = "x"\n')
    done = fishfmu("run", str(scenario), "--out", str(tmp_path / "out"), cwd=tmp_path)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith(f"error: {scenario}: "), lines[0]  # every character of the path, as given
    assert "\N{FISH}" not in done.stderr and "\N{SMILING FACE WITH OPEN MOUTH AND SMILING EYES}" not in done.stderr


def test_help_text_keeps_square_brackets(tmp_path: Path):
    done = fishfmu("run", "--help", cwd=tmp_path)
    assert done.returncode == 0
    assert "an [expect] bound failed" in " ".join(done.stdout.split())
