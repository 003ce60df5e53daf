"""The import's per-file answer (``ImportedFile``) is the reader's ``FileFacts``: its fields are the
core dataclass's, declared once there (with the descriptions the API shows), and a file's facts
read from a real board come back equal through the response's JSON."""

from __future__ import annotations

import typing
from dataclasses import asdict, fields

from pydantic import TypeAdapter

from app.api.routes.circuits import ImportedFile
from app.circuits.formats import read_layout
from app.jobs.circuit_import import FileFacts
from tests.circuits.boards import kicad_pads_board


def test_the_imported_file_declares_no_field_of_its_own():
    core = typing.get_type_hints(FileFacts)
    schema = TypeAdapter(ImportedFile).json_schema()
    assert set(schema["properties"]) == set(core) == {f.name for f in fields(ImportedFile)}
    assert set(schema["required"]) == {f.name for f in fields(FileFacts) if f.name not in ("vias", "stack")}
    described = {f.name: f.metadata["description"] for f in fields(FileFacts) if "description" in f.metadata}
    assert {name: schema["properties"][name]["description"] for name in described} == described


def test_a_boards_facts_round_trip_through_the_response():
    layout = read_layout(kicad_pads_board().encode(), "board.kicad_pcb")
    facts = FileFacts.of(layout)
    assert (facts.format, facts.units, facts.traces, facts.vias) == ("kicad", "mm", 1, 1)
    assert facts.pads == len(layout.pads) > 0 and [row["layer"] for row in facts.stack] == ["F.Cu", "B.Cu"]
    adapter = TypeAdapter(ImportedFile)
    answered = adapter.validate_json(adapter.dump_json(ImportedFile(**asdict(facts))))
    assert asdict(answered) == asdict(facts)
