"""A valid choreography and a valid inventory as tables of TOML value text, field by field, so a
test (or a fuzz seed) can replace any field by any value, even one of another type."""

from __future__ import annotations

CHOREO_FIELDS: dict[str, str] = {
    "choreo.name": '"t"',
    "choreo.arms": '["a2"]',
    "choreo.loops": "2",
    "choreo.tolerance_deg": "10.0",
    "choreo.reach_tolerance_deg": "3.0",
    "choreo.max_speed_deg_s": "90.0",
    "choreo.start_lead_s": "0.5",
    "poses.up": "[0, -30, 30, 0, 0, 0, 20]",
    "step0.duration_s": "2.0",
    "step0.easing": '"linear"',
    "step0.label": '"go"',
    "step0.all": '"up"',
    "step0.a1": "[10, -30, 30, 0, 0, 0, 20]",
    "step1.wait": '"reached"',
    "step1.arms": '["left"]',
    "step1.timeout_s": "1.0",
    "step1.label": '"hold"',
}
WHOLE_CHOREO_TABLES = ("choreo", "poses", "step")


def choreo_text(overrides: dict[str, str]) -> str:
    """The test choreography with some fields (or whole tables: ``choreo``, ``poses``,
    ``step``) replaced by TOML value text."""
    fields = {**CHOREO_FIELDS, **overrides}
    top = [f"{name} = {overrides[name]}" for name in WHOLE_CHOREO_TABLES if name in overrides]
    sections: list[tuple[str, str]] = [
        ("choreo", "[choreo]"),
        ("poses", "[poses]"),
        ("step0", "[[step]]"),
        ("step1", "[[step]]"),
    ]
    lines = [*top]
    for prefix, header in sections:
        table = prefix[:4] if prefix.startswith("step") else prefix
        if table in overrides:
            continue
        lines.append(header)
        lines += [f"{k.split('.', 1)[1]} = {v}" for k, v in fields.items() if k.startswith(prefix)]
    return "\n".join(lines) + "\n"


INVENTORY_FIELDS: dict[str, str] = {
    "fleet.name": '"lab"',
    "zenoh.endpoints": '["tcp/127.0.0.1:7447"]',
    "dds.domain_id": "0",
    "dds.peers": '["127.0.0.1"]',
    "coordinator.heartbeat_hz": "10.0",
    "coordinator.sync_lead_s": "0.3",
    "coordinator.offline_after_s": "1.0",
    "defaults.interface": '"lo"',
    "defaults.watchdog_s": "0.5",
    "arms.a1.suffix": '"_1"',
    "arms.a1.domain_id": "0",
    "arms.a1.base_xyz": "[0.0, 0.0, 0.0]",
    "arms.a1.joint_sign": "[1, 1, 1, 1, 1, 1, 1]",
    "arms.a1.lease_s": "3.0",
    "arms.a1.link_stale_s": "0.35",
    "arms.a1.contact.buffer_size": "64",
    "arms.a1.contact.methods": '["stall"]',
    "arms.a1.contact.arm.suspect_deg": "3.0",
    "arms.a1.contact.arm.oscillation_reversals": "4",
    "arms.a1.contact.gripper.force_limit_deg": "20.0",
    "arms.a2.suffix": '"_2"',
    "groups.left": '["a1"]',
}


def inventory_text(overrides: dict[str, str]) -> str:
    """The test inventory with some fields replaced by TOML value text (dotted keys under the
    top-level tables, so any field can be replaced, even by a value of another type)."""
    fields = {**INVENTORY_FIELDS, **overrides}
    lines = []
    for top in ("fleet", "zenoh", "dds", "coordinator", "defaults", "arms", "groups"):
        lines.append(f"[{top}]")
        lines += [
            f"{k.split('.', 1)[1]} = {v}" for k, v in fields.items() if k.split(".")[0] == top
        ]
    return "\n".join(lines) + "\n"
