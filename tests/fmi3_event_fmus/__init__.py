"""FMI 3.0 co-simulation FMUs with time and state events (``events.c``), built at test time with fishfmu's FMU build
machinery (:func:`fishfmu.fmu.compile.compile_binary`, fmpy's CMake project).  The Modelica Reference FMUs (Stair,
BouncingBall) are not on a package registry, so these two stand in for them with the same events."""

from __future__ import annotations

import shutil
import zipfile
from pathlib import Path

from fishfmu.fmu.compile import compile_binary

HERE = Path(__file__).parent
CS = ('<CoSimulation modelIdentifier="{id}" canHandleVariableCommunicationStepSize="true" hasEventMode="{event_mode}" '
      'mightReturnEarlyFromDoStep="{event_mode}" canReturnEarlyAfterIntermediateUpdate="false" '
      'providesIntermediateUpdate="false"/>')
VARIABLES = {
    "Stair": """
    <Float64 name="time" valueReference="0" causality="independent" variability="continuous"/>
    <Int32 name="counter" valueReference="1" causality="output" variability="discrete" initial="exact" start="0"/>
    <Float64 name="period" valueReference="2" causality="parameter" variability="fixed" start="1" unit="s"/>""",
    "Task": """
    <Float64 name="time" valueReference="0" causality="independent" variability="continuous"/>
    <Int32 name="count" valueReference="1" causality="output" variability="discrete" clocks="3" initial="exact" start="0"/>
    <Float64 name="last_tick" valueReference="2" causality="output" variability="discrete" clocks="3" initial="exact" start="0" unit="s"/>
    <Clock name="tick" valueReference="3" causality="input" variability="discrete" intervalVariability="constant" intervalDecimal="0.025"/>""",
    "BouncingBall": """
    <Float64 name="time" valueReference="0" causality="independent" variability="continuous"/>
    <Float64 name="h" valueReference="1" causality="output" variability="continuous" initial="exact" start="1" unit="m"/>
    <Float64 name="v" valueReference="2" causality="output" variability="continuous" initial="exact" start="0" unit="m/s"/>
    <Float64 name="g" valueReference="3" causality="parameter" variability="fixed" start="9.81" unit="m/s2"/>
    <Float64 name="e" valueReference="4" causality="parameter" variability="fixed" start="0.7"/>
    <Float64 name="h0" valueReference="5" causality="parameter" variability="fixed" start="1" unit="m"/>
    <Float64 name="v_min" valueReference="6" causality="parameter" variability="fixed" start="0.1" unit="m/s"/>""",
}
OUTPUTS = {"Stair": [1], "Task": [1, 2], "BouncingBall": [1, 2]}
UNITS = {"Stair": '<Unit name="s"><BaseUnit s="1"/></Unit>', "Task": '<Unit name="s"><BaseUnit s="1"/></Unit>',
         "BouncingBall": '<Unit name="m"><BaseUnit m="1"/></Unit><Unit name="m/s"><BaseUnit m="1" s="-1"/></Unit>'
                         '<Unit name="m/s2"><BaseUnit m="1" s="-2"/></Unit>'}
DEFINE = {"Stair": "MODEL_STAIR", "Task": "MODEL_TASK", "BouncingBall": "MODEL_BALL"}


def model_description(model: str, event_mode: bool) -> str:
    ident = model + ("" if event_mode else "NoEventMode")
    outputs = "".join(f'<Output valueReference="{vr}"/>' for vr in OUTPUTS[model])
    initial = "".join(f'<InitialUnknown valueReference="{vr}"/>' for vr in OUTPUTS[model])
    return (f'<?xml version="1.0" encoding="UTF-8"?>\n<fmiModelDescription fmiVersion="3.0" modelName="{ident}" '
            f'instantiationToken="{{fishfmu-test-{ident}}}" generationTool="tests/fmi3_event_fmus">\n'
            + CS.format(id=ident, event_mode=str(event_mode).lower())
            + f"\n<UnitDefinitions>{UNITS[model]}</UnitDefinitions>\n<ModelVariables>{VARIABLES[model]}\n"
            f"</ModelVariables>\n<ModelStructure>{outputs}{initial}</ModelStructure>\n</fmiModelDescription>\n")


def build_description(model: str) -> str:
    return ('<?xml version="1.0" encoding="UTF-8"?>\n<fmiBuildDescription fmiVersion="3.0">\n'
            '<BuildConfiguration modelIdentifier="ignored"><SourceFileSet language="C99">'
            '<SourceFile name="events.c"/><SourceFile name="stubs.c"/>'
            f'<PreprocessorDefinition name="{DEFINE[model]}"/>'
            '</SourceFileSet></BuildConfiguration>\n</fmiBuildDescription>\n')


def build(model: str, out_dir: Path, event_mode: bool = True) -> Path:
    """``<out_dir>/<model>[NoEventMode].fmu``: ``Stair``, ``Task`` (a periodic input clock) or ``BouncingBall``, declaring event mode and early return
    (``event_mode``) or neither (the same C code; it then handles its events inside doStep)."""
    ident = model + ("" if event_mode else "NoEventMode")
    tree = out_dir / ident
    (tree / "sources").mkdir(parents=True)
    (tree / "modelDescription.xml").write_text(model_description(model, event_mode))
    (tree / "sources" / "buildDescription.xml").write_text(build_description(model))
    for source in ("events.c", "stubs.c"):
        shutil.copy(HERE / source, tree / "sources" / source)
    compile_binary(tree, out_dir / f"{ident}-build", ident)
    fmu = out_dir / f"{ident}.fmu"
    with zipfile.ZipFile(fmu, "w", zipfile.ZIP_DEFLATED) as zf:
        for f in sorted(tree.rglob("*")):
            if f.is_file():
                zf.write(f, f.relative_to(tree).as_posix())
    return fmu
