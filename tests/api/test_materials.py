"""Material presets and a machine's dispense profile: listed once, set on a machine through
PATCH /machines/{id} (while connected too), and applied by a print (a dwell after each
dispenser switch, seen in what the mock firmware executed)."""

from __future__ import annotations

from app.jobs.kinds.toolpath import ToolpathJobParams
from app.machines.materials import BY_NAME
from hardware.mock import get_world
from tests.api.test_machines import program_text, register, upload_program
from tests.conftest import auth
from tests.helpers.jobs import wait_for

OP, VIEWER = auth("operator"), auth("viewer")


def test_the_presets_cover_pastes_inks_and_substrates_and_fit_the_toolpath_form(client):
    presets = client.get("/api/v1/materials", headers=VIEWER).json()
    kinds = {p["kind"] for p in presets}
    assert kinds == {"conductive", "dielectric", "substrate"}
    default = [p for p in presets if p["default"]]
    assert [p["name"] for p in default] == ["silver_paste"]
    assert default[0]["params"]["mode"] == "dispense" and default[0]["dispense"]["on_delay_ms"] > 0
    fields = set(ToolpathJobParams.model_fields)
    for preset in presets:
        toolpath = {k: v for k, v in preset["params"].items() if k in fields}
        parsed = ToolpathJobParams(slice_job_id="job_x", **toolpath)   # every value a toolpath accepts
        if preset["kind"] == "substrate":                                # a plastic: extruded, no dispenser
            assert parsed.mode == "extrude" and preset["dispense"] is None and parsed.nozzle_temp_c > 150
        else:                                                            # a paste or ink: no heater at all
            assert parsed.mode == "dispense" and preset["dispense"]["standoff_mm"] == preset["params"]["standoff_mm"]
    assert client.get("/api/v1/materials").status_code == 401


def test_a_machine_takes_a_preset_or_its_own_profile_while_connected(client):
    row = register(client).json()
    base = f"/api/v1/machines/{row['id']}"
    assert client.post(f"{base}/connect", headers=OP).status_code == 200
    set_ = client.patch(base, json={"material": "dielectric_ink"}, headers=OP)
    assert set_.status_code == 200, set_.text
    assert set_.json()["profile"]["dispense"] == BY_NAME["dielectric_ink"].dispense.model_dump()
    assert client.get(base, headers=OP).json()["state"] != "disconnected"   # no reconnect was needed
    own = {"material": None, "pressure_kpa": 180, "on_delay_ms": 40, "off_delay_ms": 25, "standoff_mm": 0.08,
           "feed_mm_min": 350}
    assert client.patch(base, json={"dispense": own}, headers=OP).json()["profile"]["dispense"] == own
    assert client.get(base, headers=VIEWER).json()["profile"]["dispense_on"] == "M106 S255"
    bad = client.patch(base, json={"material": "pla"}, headers=OP)          # a plastic is not dispensed
    assert bad.status_code == 422 and bad.json()["errors"][0]["loc"][-1] == "material"
    negative = client.patch(base, json={"dispense": {**own, "on_delay_ms": -1}}, headers=OP)
    assert negative.status_code == 422 and "on_delay_ms" in negative.text
    both = client.patch(base, json={"material": "silver_paste", "clear_dispense": True}, headers=OP)
    assert both.status_code == 422
    assert client.patch(base, json={"clear_dispense": True}, headers=OP).json()["profile"]["dispense"] is None


def test_a_print_dwells_after_each_dispenser_switch_by_the_machines_profile(client):
    row = register(client).json()
    base = f"/api/v1/machines/{row['id']}"
    assert client.patch(base, json={"material": "silver_paste"}, headers=OP).status_code == 200
    assert client.post(f"{base}/connect", headers=OP).status_code == 200
    program = upload_program(client, program_text(20)).json()
    job = client.post(f"{base}/print", json={"program_id": program["id"]}, headers=OP).json()
    done = wait_for(client, job["id"], timeout=60)
    assert done["status"] == "succeeded", done
    applied = done["result"]["dispense"]
    assert (applied["material"], applied["source"], applied["on_dwells"], applied["off_dwells"]) == \
        ("silver_paste", "machine profile", 1, 1)
    executed = get_world(row["id"]).transcript.commands
    on = executed.index("M106 S255")
    off = executed.index("M107", on)                 # (the connect's own M107 comes before the program)
    assert executed[on + 1] == "G4 P120" and executed[off + 1] == "G4 P80"  # the preset's 120 / 80 ms
    assert done["result"]["total"] == program["commands"] + 2
    # the print request's own profile wins over the machine's
    job = client.post(f"{base}/print", json={"program_id": program["id"], "dispense": {
        "pressure_kpa": 100, "on_delay_ms": 0, "off_delay_ms": 500, "standoff_mm": 0.1, "feed_mm_min": 300}},
        headers=OP).json()
    done = wait_for(client, job["id"], timeout=60)
    assert done["result"]["dispense"]["source"] == "request" and done["result"]["dispense"]["on_dwells"] == 0
    assert "G4 P500" in get_world(row["id"]).transcript.commands
    wrong = client.post(f"{base}/print", json={"program_id": program["id"], "material": "abs"}, headers=OP)
    assert wrong.status_code == 422 and "material" in wrong.text


def test_an_interrupted_print_resumes_with_the_profile_it_started_with(client):
    machine = client.post("/api/v1/machines", headers=OP, json={
        "name": "m", "port": "mock://", "mock": {"faults": {"disconnect_at_line": 40}}}).json()
    base = f"/api/v1/machines/{machine['id']}"
    assert client.patch(base, json={"material": "silver_paste"}, headers=OP).status_code == 200
    program = upload_program(client, program_text(80)).json()
    job = client.post(f"{base}/print", json={"program_id": program["id"]}, headers=OP).json()
    interrupted = wait_for(client, job["id"], states=("interrupted", "succeeded", "failed"), timeout=60)
    assert interrupted["status"] == "interrupted", interrupted
    total = interrupted["program_state"]["total"]
    assert total == program["commands"] + 2                                # the two dwells are in the stream
    changed = client.patch(base, json={"material": "dielectric_ink"}, headers=OP)
    assert changed.status_code == 409                                      # the interrupted print holds it
    assert client.post(f"/api/v1/jobs/{job['id']}/resume", json={"confirm": True}, headers=OP).status_code == 202
    done = wait_for(client, job["id"], timeout=60)
    assert done["status"] == "succeeded", done["error"]
    assert done["result"]["total"] == total and done["result"]["dispense"]["material"] == "silver_paste"
    executed = get_world(machine["id"]).transcript.commands
    last_off = len(executed) - 1 - executed[::-1].index("M107")
    assert executed[last_off + 1] == "G4 P80"                              # the program's end, as it started


def test_a_machine_keeps_its_own_profile_of_each_material(client):
    """A profile saved for a material is the machine's own for it: switching to another
    material and back, or a print naming the material, takes it, not the preset's start."""
    row = register(client).json()
    base = f"/api/v1/machines/{row['id']}"
    silver = {**BY_NAME["silver_paste"].dispense.model_dump(), "on_delay_ms": 55.0, "pressure_kpa": 230.0}
    assert client.patch(base, json={"dispense": silver}, headers=OP).status_code == 200
    ink = client.patch(base, json={"material": "dielectric_ink"}, headers=OP).json()["profile"]
    assert ink["dispense"] == BY_NAME["dielectric_ink"].dispense.model_dump()           # never tuned: the preset
    assert ink["dispense_by_material"]["silver_paste"] == silver
    back = client.patch(base, json={"material": "silver_paste"}, headers=OP).json()["profile"]
    assert back["dispense"] == silver                                                  # the machine's own, kept
    assert set(back["dispense_by_material"]) == {"silver_paste", "dielectric_ink"}
    assert client.patch(base, json={"material": "dielectric_ink"}, headers=OP).status_code == 200
    program = upload_program(client, program_text(20)).json()
    job = client.post(f"{base}/print", json={"program_id": program["id"], "material": "silver_paste"},
                      headers=OP).json()
    done = wait_for(client, job["id"], timeout=60)
    assert done["status"] == "succeeded", done["error"]
    applied = done["result"]["dispense"]
    assert (applied["on_delay_ms"], applied["pressure_kpa"], applied["source"]) == \
        (55.0, 230.0, "machine's profile of the material")
    carbon = client.post(f"{base}/print", json={"program_id": program["id"], "material": "carbon_paste"},
                         headers=OP).json()
    done = wait_for(client, carbon["id"], timeout=60)
    assert done["result"]["dispense"]["source"] == "material"                          # no own profile: the preset
    assert done["result"]["dispense"]["on_delay_ms"] == BY_NAME["carbon_paste"].dispense.on_delay_ms
