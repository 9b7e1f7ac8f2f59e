"""``[expect]`` bounds as a JUnit file (``--junit``): CI systems show each bound like a unit test.

The one JUnit writer (see the module docstring).(bounds on the means).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence
from xml.etree import ElementTree as ET

from fishfmu.cosim.results import ExpectResult, RunResult
from fishfmu.output.atomic import write_text_atomic

def write_junit(path: Path, suite_name: str, classname: str, expect: Sequence[ExpectResult], *,
                error: tuple[str, str | None] | None = None, on: str | None = None, time_s: float | None = None,
                properties: dict[str, str] | None = None) -> None:
    """Each [expect] bound as a JUnit test case (CI systems show them like unit tests): the one JUnit
    writer (see the module docstring).

    ``error``: (message, details) of a run that failed, as a test case ``simulation`` with an
    ``error``; ``on``: what the bounds were checked on (``"mean"`` over seeds), put before every
    case's message, which then labels passed cases too; ``time_s`` and ``properties``: the suite's
    ``time`` attribute and ``<properties>``, left out when None."""
    attrs = {"name": suite_name, "tests": str(len(expect)), "failures": str(sum(not e.ok for e in expect)),
             "errors": "1" if error is not None else "0"}
    if time_s is not None:
        attrs["time"] = f"{time_s:.3f}"
    suite = ET.Element("testsuite", attrs)
    if properties is not None:
        props = ET.SubElement(suite, "properties")
        for k, v in properties.items():
            ET.SubElement(props, "property", name=k, value=v)
    if error is not None:
        case = ET.SubElement(suite, "testcase", classname=classname, name="simulation")
        ET.SubElement(case, "error", message=error[0]).text = error[1]
    for e in expect:
        case = ET.SubElement(suite, "testcase", classname=classname, name=f"expect.{e.kpi}")
        if on is not None:
            ET.SubElement(case, "failure" if not e.ok else "system-out", message=f"{on} {e.message}").text = e.message
        elif not e.ok:
            ET.SubElement(case, "failure", message=e.message).text = e.message
        else:
            ET.SubElement(case, "system-out").text = e.message
    ET.indent(suite)
    write_text_atomic(Path(path), ET.tostring(suite, encoding="unicode", xml_declaration=True) + "\n")

def junit_args_of_run(result: RunResult, scenario_file: str | None) -> dict[str, Any]:
    """:func:`write_junit`'s arguments for a single run: suite ``fishfmu:<run name>``, its wall time,
    scenario and seed as properties, an error case when the run did not finish ok."""
    name = result.scenario.run.name
    return {"suite_name": f"fishfmu:{name}", "classname": f"fishfmu.{name}", "expect": result.expect,
            "error": (result.error or "failed", result.error) if result.status != "ok" else None,
            "time_s": result.wall_s,
            "properties": {"scenario": str(scenario_file or name), "seed": str(result.scenario.run.seed)}}
